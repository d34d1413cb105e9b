"""Decoder throughput: points/s for forward+backward+Adam (training), forward (inference), and
forward+backward to the inputs on 3000 points as a fit runs it, in float32 and with bfloat16
matrix products (``FitSettings.decoder_dtype``).

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


def fit_throughput(name: str, *, bfloat16: bool, batch: int = 3000, repeats: int = 20) -> float:
    """Points/s of a fit's decoder pass: forward, and backward to the points and codes (weights frozen)."""
    decoder = Decoder(ARCHITECTURES[name]).eval().requires_grad_(False)
    x = (torch.rand(batch, 3) * 2 - 1).requires_grad_(True)
    z = (torch.randn(batch, ARCHITECTURES[name].latent_size) * 0.1).requires_grad_(True)
    times = []
    for _ in range(repeats + 3):
        t = time.perf_counter()
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bfloat16):
            f = decoder(x, z)
        torch.autograd.grad(f.float().sum(), [x, z])
        times.append(time.perf_counter() - t)
    return batch / sorted(times[3:])[len(times[3:]) // 2]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(f"| architecture | parameters | train points/s | inference points/s | fit points/s, float32 "
          f"| fit points/s, bfloat16 |  ({args.threads} threads)")
    print("|---|---|---|---|---|---|")
    for name in ARCHITECTURES:
        params, train, infer = throughput(name)
        fit32, fit16 = (fit_throughput(name, bfloat16=bf) for bf in (False, True))
        print(f"| {name} | {params:,} | {train:,.0f} | {infer:,.0f} | {fit32:,.0f} | {fit16:,.0f} |")


if __name__ == "__main__":
    main()
