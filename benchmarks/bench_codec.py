"""Shape-code sizes, encode/decode times and latent error for d = 64 and 256 in each encoding.

    nice -n 19 .venv/bin/python benchmarks/bench_codec.py [--repeats 2000] [--model chair]

With ``--model`` (a shipped name or a file) it also times turning a code into a mesh
(marching cubes at 128³), which dominates decoding by orders of magnitude.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from jsrte.codec.format import ShapeCode, decode, encode, quantize_int8
from jsrte.geometry.sim3 import Sim3, axis_angle_matrix

FORMATS = ("fp32", "fp16", "int8")


def per_call_us(fn, repeats: int) -> float:
    fn()
    started = time.perf_counter()
    for _ in range(repeats):
        fn()
    return (time.perf_counter() - started) / repeats * 1e6


def code_of(d: int, rng: np.random.Generator) -> ShapeCode:
    r = axis_angle_matrix(np.array([0.0, 1.0, 0.0]), 1.0)
    return ShapeCode(rng.normal(0.0, 0.1, d).astype(np.float32), Sim3(1.4, r, [0.3, 0.0, 2.0]), "chair",
                     bytes(16))


def codec_table(repeats: int) -> None:
    rng = np.random.default_rng(0)
    print("| d | latent | bytes | encode µs | decode µs | max abs latent error | int8 step a/2 |")
    print("|---|---|---|---|---|---|---|")
    for d in (64, 256):
        code = code_of(d, rng)
        for fmt in FORMATS:
            data = encode(code, latent_format=fmt)
            t_enc = per_call_us(lambda code=code, fmt=fmt: encode(code, latent_format=fmt), repeats)
            t_dec = per_call_us(lambda data=data: decode(data), repeats)
            err = float(np.abs(decode(data).latent - code.latent).max())
            half = f"{quantize_int8(code.latent)[0] / 2:.2e}" if fmt == "int8" else "-"
            print(f"| {d} | {fmt} | {len(data)} | {t_enc:.1f} | {t_dec:.1f} | {err:.2e} | {half} |")


def mesh_timing(model_name: str, resolution: int) -> None:
    from jsrte.codec.convert import mesh_from_code
    from jsrte.model.registry import resolve_model

    model = resolve_model(model_name)
    latent = model.codes[0].numpy()
    code = ShapeCode(latent, Sim3.identity(), model.name, bytes.fromhex(model.meta["sha256"])[:16])
    started = time.perf_counter()
    mesh = mesh_from_code(code, model, resolution=resolution)
    seconds = time.perf_counter() - started
    faces = 0 if mesh is None else len(mesh.faces)
    print(f"\nmesh from code ({model.name}, d={latent.size}, {resolution}³): {seconds:.2f} s, {faces} faces")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=2000)
    parser.add_argument("--model", default=None, help="Also time code -> mesh with this model.")
    parser.add_argument("--resolution", type=int, default=128)
    args = parser.parse_args()
    codec_table(args.repeats)
    if args.model:
        mesh_timing(args.model, args.resolution)


if __name__ == "__main__":
    main()
