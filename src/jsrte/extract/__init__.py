"""Meshes from signed distance functions: marching cubes on dense, coarse-to-fine or narrow-band grids."""

from jsrte.extract.marching import (
    Extraction,
    SdfFunction,
    extract_coarse_to_fine,
    extract_dense,
    extract_narrow_band,
)

__all__ = ["Extraction", "SdfFunction", "extract_coarse_to_fine", "extract_dense", "extract_narrow_band"]
