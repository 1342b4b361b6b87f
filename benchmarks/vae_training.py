"""Time training the generator's VAE on the paper's 10,000 worlds (paper §5.2.1), per environment.

    python benchmarks/vae_training.py --env racing --out runs/generators/racing
    python benchmarks/vae_training.py --env harvest --out runs/generators/harvest

Makes (or reuses) OUT/dataset.npz, trains with the default ``VAEConfig`` (no checkpointing
during the timed run), saves the generator to OUT, and records the dataset and training
times with the per-epoch losses. Then `worldagent generator report OUT` measures its quality.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import record  # noqa: E402
from worldagent.envs import registry  # noqa: E402
from worldagent.worlds.dataset import WorldDataset, make_dataset  # noqa: E402
from worldagent.worlds.generator import build_generator, save_generator  # noqa: E402
from worldagent.worlds.vae import VAEConfig, train_vae  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", choices=registry.names(), required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--num-worlds", type=int, default=10_000)
    args = parser.parse_args()

    dataset_path = args.out / "dataset.npz"
    start = time.perf_counter()
    if dataset_path.exists():
        data = WorldDataset.load(dataset_path, env=args.env)
    else:
        data = make_dataset(args.env, args.num_worlds, 0, progress=False)
        data.save(dataset_path)
    dataset_seconds = time.perf_counter() - start
    config = VAEConfig()
    start = time.perf_counter()
    vae = train_vae(data, config, progress=False)
    train_seconds = time.perf_counter() - start
    save_generator(args.out, vae, dataset_path, build_generator(vae, data))
    result = {
        "env": args.env,
        "num_worlds": len(data),
        "dataset_seconds": round(dataset_seconds, 2),
        "train_seconds": round(train_seconds, 2),
        "epochs": config.epochs,
        "final": vae.history[-1],
        "holdout_loss_by_epoch": [round(h["holdout_loss"], 2) for h in vae.history],
    }
    print(
        f"{args.env}: dataset {dataset_seconds:.1f} s, training {train_seconds:.1f} s ({config.epochs} epochs), "
        f"held-out loss {vae.history[0]['holdout_loss']:.1f} -> {vae.history[-1]['holdout_loss']:.1f}"
    )
    print(f"recorded in {record(f'vae_training_{args.env}', result)}")


if __name__ == "__main__":
    main()
