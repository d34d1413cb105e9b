"""Surface metrics: the paper's F-score at a fraction of the bounding-sphere radius, Chamfer."""

from jsrte.metrics.surface import FScore, bounding_sphere, chamfer, fscore, sample_surface

__all__ = ["FScore", "bounding_sphere", "chamfer", "fscore", "sample_surface"]
