"""Meshes from signed distance functions: marching cubes on dense or coarse-to-fine grids."""

from jsrte.extract.marching import Extraction, SdfFunction, extract_coarse_to_fine, extract_dense

__all__ = ["Extraction", "SdfFunction", "extract_coarse_to_fine", "extract_dense"]
