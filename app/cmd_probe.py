"""`photoar probe sh PROBE --mapping mirrorball|angular|latlong [--up x|y|z]` (lighting/probe.py).

Prints the 9 SH coefficients of the probe's incident radiance (Ramamoorthi-Hanrahan order and
normalisation) as JSON {"L00": [r,g,b], ..., "L22": [r,g,b]}, in the project's world frame
(+Y up): --up names the axis of the map's own frame that points up (default: z for lat-long,
pbrt; y for angular and mirror-ball maps, whose frame is Debevec's, x right, y up, z towards the
camera). Radiance in the file's units.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

DEFAULT_UP = {"latlong": "z", "angular": "y", "mirrorball": "y"}


def register(sub) -> None:
    p = sub.add_parser("probe", help="light-probe tools")
    ps = p.add_subparsers(dest="probe_command", required=True)
    s = ps.add_parser("sh", help="print the 9 SH coefficients of a probe image as JSON")
    s.add_argument("probe", type=Path, help="HDR probe image (.exr, .hdr or .pfm)")
    s.add_argument("--mapping", choices=["mirrorball", "angular", "latlong"], required=True)
    s.add_argument("--up", choices=["x", "y", "z"], default=None,
                   help="axis of the map's frame that is up (default z for latlong, y otherwise)")
    s.add_argument("--rim", type=float, default=None, help="mirror ball: largest valid radius (default 0.98)")
    s.set_defaults(run=run)


def run(a: argparse.Namespace) -> int:
    from lighting import hdr, probe
    from recon.io import dumps_json

    rad = hdr.load_radiance(a.probe)
    R = probe.up_rotation(a.up or DEFAULT_UP[a.mapping])
    if a.mapping == "mirrorball":
        R = R @ probe.R_DEBEVEC_FROM_CV  # OpenCV probe-camera axes -> Debevec's frame -> world
    try:
        c = probe.sh_from_probe(rad, a.mapping, R, rim=a.rim if a.rim is not None else probe.DEFAULT_RIM)
    except ValueError as e:
        raise ValueError(f"{a.probe}: {e}") from None
    if not np.all(np.isfinite(c)):
        raise RuntimeError(f"{a.probe}: SH fit is not finite")
    print(dumps_json(probe.sh_to_dict(c), sort_keys=False))
    return 0
