"""Scans: a virtual depth camera (objects on a floor), scan loading, and the paper's real-scan
preprocessing (floor plane and up axis, outliers, hidden points, outward normals).

Open3D is imported inside the functions that use it, so importing this package stays cheap.
"""

from jsrte.scans.io import ScanCloud, ScanInfo, load_scan, read_scan_info
from jsrte.scans.preprocess import (
    Floor,
    PreparedScan,
    PrepareSettings,
    check_units,
    estimate_normals,
    hidden_point_removal,
    prepare_scan,
    remove_outliers,
    segment_floor,
)
from jsrte.scans.scanner import ScannerSettings, VirtualScan, scan_mesh, write_scan

__all__ = [
    "Floor",
    "PrepareSettings",
    "PreparedScan",
    "ScanCloud",
    "ScanInfo",
    "ScannerSettings",
    "VirtualScan",
    "check_units",
    "estimate_normals",
    "hidden_point_removal",
    "load_scan",
    "prepare_scan",
    "read_scan_info",
    "remove_outliers",
    "scan_mesh",
    "segment_floor",
    "write_scan",
]
