"""The ``.jsrte`` shape code: a latent code and a similarity transform in a few hundred bytes.

The paper (section 4.3) stores a shape as its latent vector z and the similarity transform
(a 4x4 matrix); anyone holding the same decoder turns it back into a mesh. This module is
that file, made safe to pass around: a versioned header, the identity of the model the code
belongs to, and a checksum, so a corrupt, truncated, foreign or mismatched file is refused
instead of decoding to a wrong shape.

Byte layout (format version 1; little-endian, no padding; ``n`` = name length, ``d`` = latent size)

======  ==========  =====================================================================
offset  size        field
======  ==========  =====================================================================
0       4           magic ``b"JSRT"``
4       1           format version, u8 (= 1)
5       1           flags, u8: reserved, must be 0 (a reader refuses unknown bits)
6       1           latent encoding, u8: 0 = fp32, 1 = fp16, 2 = int8 (affine, per vector)
7       2           latent dimension d, u16 (>= 1)
9       1           model name length n, u8 (<= 64)
10      n           model name, UTF-8 (e.g. ``chair``)
10+n    16          model hash: the first 16 bytes of the SHA-256 of the model file
26+n    4           scale s, f32 (> 0)
30+n    36          rotation R, 3x3 f32, row-major (a rotation: RᵀR = I, det R = +1)
66+n    12          translation t, 3 f32 (scan units, metres)
78+n    P           latent payload:
                    fp32: d x f32 (P = 4d);  fp16: d x f16 (P = 2d);
                    int8: scale a f32, offset b f32, then d x u8 q (P = 8 + d),
                    z_i = b + a * q_i
78+n+P  4           CRC-32 (zlib.crc32) of every byte before it, u32
======  ==========  =====================================================================

The transform maps canonical coordinates to the scan's: ``x -> s * R @ x + t``
(``scan_from_canonical``). It is stored as s, R and t in fp32 (52 bytes) rather than the
paper's 4x4 fp32 matrix (64 bytes): 12 bytes smaller, and the scale stays separate from the
rotation so no cube root of a determinant is needed to split them. A quaternion would save
20 more bytes but would not round-trip R bit-exactly.

Sizes: ``82 + n + P`` bytes. With the model name ``chair`` (n = 5):

=====  ======  ======  ======
d      fp32    fp16    int8
=====  ======  ======  ======
64     343     215     159
256    1111    599     351
=====  ======  ======  ======

(the paper's 256-d code with a 4x4 fp32 matrix: 1088 bytes, without header or checksum).

Precision (per latent coordinate; z the input, z' what :func:`decode` returns):

- fp32: exact (the latent is fp32). The transform is rounded to fp32 on encoding
  (relative error <= 2^-24, well under a micrometre at metre scale); a code read from a
  file re-encodes to the same bytes.
- fp16: round to nearest, ``|z - z'| <= max(2^-11 |z|, 2^-25)`` (|z| must be < 65520).
- int8: affine over the vector's range, ``a = (max z - min z) / 255`` (rounded up to fp32),
  ``b = min z``, ``q = round((z - b) / a)``; ``|z - z'| <= a / 2`` (plus half an fp32 ulp
  of z' from the final cast).
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from typing import Literal

import numpy as np

from jsrte.errors import JsrteError
from jsrte.geometry.sim3 import Sim3

MAGIC = b"JSRT"
VERSION = 1
LatentFormat = Literal["fp32", "fp16", "int8"]
ENCODINGS: dict[str, int] = {"fp32": 0, "fp16": 1, "int8": 2}
ENCODING_NAMES: dict[int, str] = {v: k for k, v in ENCODINGS.items()}
NAME_MAX_BYTES = 64
HASH_BYTES = 16
MAX_LATENT_SIZE = 0xFFFF
KNOWN_FLAGS = 0

_PREFIX = struct.Struct("<4sBBBHB")  # magic, version, flags, encoding, latent dim, name length
_TRANSFORM = struct.Struct("<13f")  # s, R (row-major), t
_INT8_PARAMS = struct.Struct("<2f")  # scale a, offset b
_CRC = struct.Struct("<I")
FIXED_BYTES = _PREFIX.size + HASH_BYTES + _TRANSFORM.size + _CRC.size  # 82

ROTATION_TOLERANCE = 1e-5
"""Largest |RᵀR - I| entry and |det R - 1| accepted when reading (fp32 rounding is ~1e-7)."""
SCALE_RANGE = (1e-5, 1e5)
"""Scales accepted (scan units per canonical unit: an object from 10 µm to 100 km across in metres)."""
MAX_TRANSLATION = 1e6
"""Largest |t| entry accepted (scan units)."""
MAX_LATENT_ABS = 1e5
"""Largest |z| entry accepted (trained codes are of order 0.01 to 1)."""


@dataclass(eq=False)
class ShapeCode:
    """A shape as the paper compresses it: a latent code, a transform, and its model.

    Attributes
    ----------
    latent : (d,) float32 latent code
    transform : ``scan_from_canonical`` Sim3 (canonical unit-sphere frame -> scan units)
    model_name : short name of the model (<= 64 bytes of UTF-8), used to find a shipped model
    model_hash : 16 bytes, the start of the SHA-256 of the model file
    """

    latent: np.ndarray
    transform: Sim3
    model_name: str
    model_hash: bytes

    def __post_init__(self) -> None:
        self.latent = np.array(self.latent, dtype=np.float32).reshape(-1)
        self.model_hash = bytes(self.model_hash)
        if len(self.model_hash) != HASH_BYTES:
            raise ValueError(f"model_hash must be {HASH_BYTES} bytes, got {len(self.model_hash)}")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ShapeCode):
            return NotImplemented
        a, b = self.transform, other.transform
        return (self.model_name == other.model_name and self.model_hash == other.model_hash
                and np.array_equal(self.latent, other.latent) and a.s == b.s
                and np.array_equal(a.R, b.R) and np.array_equal(a.t, b.t))

    @property
    def model_hash_hex(self) -> str:
        return self.model_hash.hex()


def model_hash_prefix(sha256_hex: str) -> bytes:
    """The 16 stored bytes of a model's SHA-256 given as 64 hex digits."""
    try:
        digest = bytes.fromhex(sha256_hex)
    except (TypeError, ValueError):
        raise JsrteError(f"model hash {sha256_hex!r} is not a hex SHA-256") from None
    if len(digest) != 32:
        raise JsrteError(f"model hash {sha256_hex!r} is not a SHA-256 (32 bytes)")
    return digest[:HASH_BYTES]


def encoded_size(latent_size: int, latent_format: LatentFormat = "fp32", *, name_bytes: int = 5) -> int:
    """Bytes of a code with a ``latent_size``-d latent and a model name of ``name_bytes`` bytes."""
    return FIXED_BYTES + name_bytes + _payload_size(ENCODINGS[latent_format], latent_size)


# --- encoding ------------------------------------------------------------------------------


def encode(code: ShapeCode, *, latent_format: LatentFormat = "fp32") -> bytes:
    """The bytes of ``code`` (see the module docstring for the layout).

    Raises ``JsrteError`` for what the format cannot hold: an unknown ``latent_format``, a
    model name over 64 bytes, an empty or too long latent, non-finite values, a latent out of
    fp16 range, a non-positive scale.
    """
    if latent_format not in ENCODINGS:
        raise JsrteError(f"unknown latent format {latent_format!r}; known: {', '.join(ENCODINGS)}")
    name = code.model_name.encode("utf-8")
    if len(name) > NAME_MAX_BYTES:
        raise JsrteError(f"model name {code.model_name!r} is {len(name)} bytes of UTF-8; "
                         f"a shape code holds at most {NAME_MAX_BYTES}")
    latent = code.latent
    if not 1 <= latent.size <= MAX_LATENT_SIZE:
        raise JsrteError(f"latent size {latent.size} is outside 1..{MAX_LATENT_SIZE}")
    if not np.all(np.isfinite(latent)):
        raise JsrteError("the latent code holds non-finite values")
    if np.abs(latent).max() > MAX_LATENT_ABS:
        raise JsrteError(f"a latent value ({np.abs(latent).max():.3g}) exceeds {MAX_LATENT_ABS:g}")
    encoding = ENCODINGS[latent_format]
    head = _PREFIX.pack(MAGIC, VERSION, KNOWN_FLAGS, encoding, latent.size, len(name))
    body = head + name + code.model_hash + _pack_transform(code.transform) + _pack_latent(latent, encoding)
    return body + _CRC.pack(zlib.crc32(body))


def _pack_transform(transform: Sim3) -> bytes:
    values = np.concatenate([[transform.s], transform.R.reshape(-1), transform.t])
    if not np.all(np.isfinite(values)):
        raise JsrteError("the transform holds non-finite values")
    stored = values.astype(np.float32)
    if not np.all(np.isfinite(stored)) or not stored[0] > 0:
        raise JsrteError(f"the transform does not fit in fp32 with a positive scale (s = {transform.s})")
    if not is_rotation(stored[1:10].astype(np.float64).reshape(3, 3)):
        raise JsrteError("the transform's R is not a rotation matrix")
    problem = transform_range_problem(float(stored[0]), stored[10:])
    if problem:
        raise JsrteError(f"the transform is out of range: {problem}")
    return _TRANSFORM.pack(*stored.tolist())


def transform_range_problem(scale: float, translation: np.ndarray) -> str | None:
    """What is absurd about a code's scale or translation (None if both are in range)."""
    lo, hi = SCALE_RANGE
    if not lo <= scale <= hi:
        return f"scale {scale:.3g} is outside {lo:g}..{hi:g}"
    largest = float(np.abs(translation).max())
    if largest > MAX_TRANSLATION:
        return f"translation {largest:.3g} exceeds {MAX_TRANSLATION:g}"
    return None


def is_rotation(r: np.ndarray) -> bool:
    """Whether ``r`` (3, 3) is a rotation to within :data:`ROTATION_TOLERANCE`."""
    return bool(np.abs(r.T @ r - np.eye(3)).max() <= ROTATION_TOLERANCE
                and abs(np.linalg.det(r) - 1.0) <= ROTATION_TOLERANCE)


def _pack_latent(latent: np.ndarray, encoding: int) -> bytes:
    if encoding == ENCODINGS["fp32"]:
        return latent.astype("<f4").tobytes()
    if encoding == ENCODINGS["fp16"]:
        with np.errstate(over="ignore"):
            half = latent.astype("<f2")
        if not np.all(np.isfinite(half)):
            raise JsrteError("the latent code exceeds the fp16 range (|z| < 65520); use --latent fp32")
        return half.tobytes()
    scale, offset, q = quantize_int8(latent)
    return _INT8_PARAMS.pack(scale, offset) + q.tobytes()


def quantize_int8(latent: np.ndarray) -> tuple[float, float, np.ndarray]:
    """Affine 8-bit quantization of a finite vector (d,).

    Returns
    -------
    scale : float (an fp32 value), a >= (max - min) / 255
    offset : float (an fp32 value), b = min
    q : (d,) uint8 with latent ≈ b + a * q and ``|latent - (b + a q)| <= a / 2``
    """
    z = np.asarray(latent, dtype=np.float32).astype(np.float64)
    offset = float(np.float32(z.min()))
    scale32 = np.float32((z.max() - offset) / 255.0)
    if float(scale32) * 255.0 < z.max() - offset:  # round the step up so max stays inside
        scale32 = np.nextafter(scale32, np.float32(np.inf))
    scale = float(scale32)
    if not np.isfinite(scale):
        raise JsrteError("the latent code's range exceeds fp32; use --latent fp32")
    if scale == 0.0:
        return 0.0, offset, np.zeros(z.shape, np.uint8)
    q = np.clip(np.rint((z - offset) / scale), 0, 255).astype(np.uint8)
    return scale, offset, q


def dequantize_int8(scale: float, offset: float, q: np.ndarray) -> np.ndarray:
    """``b + a * q`` (d,) float32, computed in float64."""
    return (offset + scale * np.asarray(q, np.float64)).astype(np.float32)


# --- decoding ------------------------------------------------------------------------------


def decode(data: bytes, *, source: str | None = None) -> ShapeCode:
    """Parse a shape code; ``JsrteError`` naming ``source`` for anything but a valid file.

    Checks, in order: the magic, the format version, the length the header announces, the
    CRC-32, the flags, then the values (UTF-8 name, positive finite scale, a rotation,
    finite latent). Never returns a code that the checks did not pass.
    """
    try:
        return _decode(bytes(data), source)
    except JsrteError:
        raise
    except (struct.error, ValueError, UnicodeDecodeError, OverflowError) as exc:  # defence in depth
        raise JsrteError(f"corrupt shape code ({exc})", source) from exc


def _decode(data: bytes, source: str | None) -> ShapeCode:
    def fail(message: str) -> JsrteError:
        return JsrteError(message, source)

    if len(data) < len(MAGIC) or data[: len(MAGIC)] != MAGIC:
        if MAGIC.startswith(data[: len(MAGIC)]) and len(data) < len(MAGIC):
            raise fail(f"truncated shape code ({len(data)} bytes)")
        raise fail(f"not a jsrte shape code (starts with {data[:4]!r}, expected {MAGIC!r})")
    if len(data) < _PREFIX.size:
        raise fail(f"truncated shape code ({len(data)} bytes, shorter than the {_PREFIX.size}-byte header)")
    _, version, flags, encoding, dim, name_len = _PREFIX.unpack_from(data, 0)
    if version != VERSION:
        newer = "written by a newer jsrte, or " if version > VERSION else ""
        raise fail(f"shape code format version {version} is not supported (this jsrte reads version "
                   f"{VERSION}); the file was {newer}is corrupt")
    if encoding not in ENCODING_NAMES:
        raise fail(f"corrupt shape code: unknown latent encoding {encoding}")
    if name_len > NAME_MAX_BYTES or dim == 0:
        raise fail(f"corrupt shape code: bad header (name length {name_len}, latent size {dim})")
    expected = FIXED_BYTES + name_len + _payload_size(encoding, dim)
    if len(data) != expected:
        what = "truncated" if len(data) < expected else "corrupt"
        raise fail(f"{what} shape code: the header announces {expected} bytes, the file has {len(data)}")
    (stored_crc,) = _CRC.unpack_from(data, expected - _CRC.size)
    if zlib.crc32(data[: expected - _CRC.size]) != stored_crc:
        raise fail("corrupt shape code: checksum (CRC-32) mismatch")
    if flags & ~KNOWN_FLAGS:
        raise fail(f"shape code uses unknown flags 0x{flags:02x} (written by a newer jsrte?)")
    at = _PREFIX.size
    try:
        name = data[at: at + name_len].decode("utf-8")
    except UnicodeDecodeError:
        raise fail("corrupt shape code: the model name is not UTF-8") from None
    at += name_len
    model_hash = data[at: at + HASH_BYTES]
    at += HASH_BYTES
    transform = _unpack_transform(data, at, fail)
    at += _TRANSFORM.size
    latent = _unpack_latent(data, at, encoding, dim, fail)
    return ShapeCode(latent=latent, transform=transform, model_name=name, model_hash=model_hash)


def _payload_size(encoding: int, dim: int) -> int:
    return {0: 4 * dim, 1: 2 * dim, 2: _INT8_PARAMS.size + dim}[encoding]


def _unpack_transform(data: bytes, at: int, fail) -> Sim3:  # noqa: ANN001
    values = np.array(_TRANSFORM.unpack_from(data, at), dtype=np.float64)
    s, r, t = values[0], values[1:10].reshape(3, 3), values[10:]
    if not np.all(np.isfinite(values)) or not s > 0:
        raise fail("corrupt shape code: the transform is not finite with a positive scale")
    if not is_rotation(r):
        raise fail("corrupt shape code: the stored rotation is not a rotation matrix")
    problem = transform_range_problem(float(s), t)
    if problem:
        raise fail(f"corrupt shape code: {problem}")
    return Sim3(float(s), r, t)


def _unpack_latent(data: bytes, at: int, encoding: int, dim: int, fail) -> np.ndarray:  # noqa: ANN001
    if encoding == ENCODINGS["fp32"]:
        latent = np.frombuffer(data, dtype="<f4", count=dim, offset=at).astype(np.float32)
    elif encoding == ENCODINGS["fp16"]:
        latent = np.frombuffer(data, dtype="<f2", count=dim, offset=at).astype(np.float32)
    else:
        scale, offset = _INT8_PARAMS.unpack_from(data, at)
        if not (np.isfinite(scale) and np.isfinite(offset) and scale >= 0):
            raise fail("corrupt shape code: bad int8 quantization parameters")
        q = np.frombuffer(data, dtype=np.uint8, count=dim, offset=at + _INT8_PARAMS.size)
        latent = dequantize_int8(scale, offset, q)
    if not np.all(np.isfinite(latent)):
        raise fail("corrupt shape code: the latent code holds non-finite values")
    if np.abs(latent).max() > MAX_LATENT_ABS:
        raise fail(f"corrupt shape code: a latent value ({np.abs(latent).max():.3g}) exceeds {MAX_LATENT_ABS:g}")
    return latent
