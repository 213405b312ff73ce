"""How far a projector may stray from beside the camera before the composite's codes cannot tell orders
apart: for a projector turned about its own axis (its rows against the baseline) and one above or below
the camera's axis (negative: above), the decoder's separation of two orders' codes over the working
range (CompositeDecoder: min_separation less twice row_fit_error; it refuses a rig under
reconstruct.MIN_SEPARATION_RAD, 0.2 rad) and how many of the coarse code's turns the range spans.

No images: the code models come from the simulated rig's exact geometry (board.model_from_geometry with
its projector's pose and intrinsics, as a board calibration would find them). Both misalignments move the
projector row a camera pixel sees with depth, which moves each code by a share of an order per order: where
that cancels the coarse code's own step (2 pi / 36 an order), two orders of the range show the same codes.

    python scripts/composite_alignment.py [--near 1100 --far 1300]   (about a minute)
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from fpp_nodes.core import reconstruct
from fpp_nodes.core.board import model_from_geometry
from fpp_nodes.core.calibration import Calibration
from fpp_nodes.core.simulation import Rig

ROLLS_DEG = np.arange(-6.0, 6.01, 0.5)
OFFSETS_MM = np.arange(-100.0, 100.1, 5.0)


def separation(rig: Rig, working_range_mm: tuple[float, float]) -> tuple[float, int]:
    """(the decoder's separation of two orders' codes, rad; the coarse code's turns it looks in) on rig."""
    rotation = rig.projector_rotation()
    focal, cx, cy = rig.projector_intrinsics()
    projector = np.array([[focal, 0.0, cx], [0.0, focal, cy], [0.0, 0.0, 1.0]])
    translation = -rotation @ rig.projector_center
    patterns = rig.pattern_set()
    model, codes, _ = model_from_geometry(
        rig.camera(), patterns, rotation, translation, projector, np.zeros(5), working_range_mm
    )
    calibration = Calibration(rig.camera(), model, patterns, rig.standoff_mm, codes, working_range_mm)
    limit, reconstruct.MIN_SEPARATION_RAD = reconstruct.MIN_SEPARATION_RAD, -np.inf  # measure, do not refuse
    try:
        decoder = reconstruct.CompositeDecoder(calibration)
    finally:
        reconstruct.MIN_SEPARATION_RAD = limit
    return decoder.min_separation - 2 * decoder.row_fit_error, decoder.coarse_turns


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--near", type=float, default=1100.0, help="the working range's near end (mm)")
    parser.add_argument("--far", type=float, default=1300.0, help="the working range's far end (mm)")
    args = parser.parse_args(argv)
    working, base = (args.near, args.far), Rig()
    limit = reconstruct.MIN_SEPARATION_RAD
    print(
        f"the default rig (baseline {base.baseline_mm:g} mm, stand-off {base.standoff_mm:g} mm), working range "
        f"{args.near:g}-{args.far:g} mm; decodes where the separation is at least {limit} rad"
    )
    for title, field, values, unit in (
        ("projector turned about its axis", "projector_roll_deg", ROLLS_DEG, "deg"),
        ("projector below the camera's axis (negative: above)", "projector_below_mm", OFFSETS_MM, "mm"),
    ):
        print(f"\n{title:52} {'separation rad':>15} {'coarse turns':>13}  decodes")
        for value in values:
            gap, turns = separation(replace(base, **{field: float(value)}), working)
            decodes = "yes" if gap >= limit else "no"
            print(f"{value:+48.1f} {unit:3} {gap:15.2f} {turns:13d}  {decodes}")


if __name__ == "__main__":
    main()
