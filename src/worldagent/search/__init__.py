"""Phase 3 of the paper (§3.3, §4.4): ask/tell optimisers over latents, campaigns."""
