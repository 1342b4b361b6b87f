"""Phase 2 of the paper (§4.3, §5.3): world distributions, policies, PPO, rollouts, metrics."""
