"""SDF samples: from meshes (DeepSDF style) and from scans (paper supplementary)."""

from jsrte.sdf.mesh_sdf import SdfSamples, sample_sdf, signed_distance

__all__ = ["SdfSamples", "sample_sdf", "signed_distance"]
