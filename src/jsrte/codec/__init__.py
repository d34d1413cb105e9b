"""Compact shape codes (the paper's section 4.3): a latent code and a similarity transform in a
small, versioned, checksummed binary file (``.jsrte``), tied to the model that decodes it.

The byte layout is documented in :mod:`jsrte.codec.format` and docs/codec.md.
"""

from jsrte.codec.convert import code_from_fit_dir, code_from_result, mesh_from_code, model_for_code, read_code
from jsrte.codec.format import ShapeCode, decode, encode, encoded_size

__all__ = ["ShapeCode", "code_from_fit_dir", "code_from_result", "decode", "encode", "encoded_size",
           "mesh_from_code", "model_for_code", "read_code"]
