"""Decoder throughput: points/s for forward+backward+Adam (training) and forward (inference).

Run: .venv/bin/python benchmarks/bench_decoder.py [--threads 2]
"""

from __future__ import annotations

import argparse
import time

import torch

from jsrte.model.decoder import ARCHITECTURES, Decoder, count_parameters


def throughput(name: str, batch: int = 16384, repeats: int = 5) -> tuple[int, float, float]:
    config = ARCHITECTURES[name]
    decoder = Decoder(config)
    optimizer = torch.optim.Adam(decoder.parameters(), lr=1e-4)
    x, z = torch.rand(batch, 3) * 2 - 1, torch.randn(batch, config.latent_size) * 0.1
    times = []
    for _ in range(repeats + 1):
        t = time.perf_counter()
        loss = decoder(x, z).abs().mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        times.append(time.perf_counter() - t)
    train = batch / sorted(times[1:])[len(times[1:]) // 2]
    decoder.eval().fold_weight_norm()
    with torch.no_grad():
        times = []
        for _ in range(repeats + 1):
            t = time.perf_counter()
            decoder(x, z[0])
            times.append(time.perf_counter() - t)
    infer = batch / sorted(times[1:])[len(times[1:]) // 2]
    return count_parameters(decoder), train, infer


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(f"| architecture | parameters | train points/s | inference points/s |  ({args.threads} threads)")
    print("|---|---|---|---|")
    for name in ARCHITECTURES:
        params, train, infer = throughput(name)
        print(f"| {name} | {params:,} | {train:,.0f} | {infer:,.0f} |")


if __name__ == "__main__":
    main()
