"""Phase 1 of the paper (§3.1, §4.2, §5.2.1): datasets of worlds, a VAE over them, repair, G(z)."""
