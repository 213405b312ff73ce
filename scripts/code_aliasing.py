"""Where the composite's codes repeat: for the shipped codes, and with a third, coarser one, the share of
the default rig's pixels at which a surface outside the working range shows codes that name an order
inside it (the decoder then gives it a depth in the range, an order or more off).

No network and no noise: each grating's phase from the rig's geometry (the projector pixel (x, y) each
camera pixel sees at each depth, Rig.to_projector), a code telling K orders apart with rows P projector
pixels apart 2 pi (x f_max / K / W + y / P), as patterns.composite_phases. The decoder
(CompositeDecoder.code_phase) takes an order of the working range whose codes all lie within half the
closest two orders' codes (min_separation, root sum of squares) of a pixel's; here, for pixels every 16 px
and 550 depths from 500 mm to 50 m outside the range, whether one does. Also printed: min_separation
(the margin of every decision inside the range is half of it), the closest any surface outside the
range comes to an order inside (its codes' least miss, rad: below half of min_separation it names that
order), and the carrier's amplitude if the codes keep their share of it (CODE_AMPLITUDE /
CARRIER_AMPLITUDE; the shipped 0.4): what each code costs in phase noise.

    PYTHONPATH=fpp_nodes:. python scripts/code_aliasing.py   (about a minute)
"""

from __future__ import annotations

import numpy as np

from fpp_nodes.core.patterns import CARRIER_AMPLITUDE, CODE_AMPLITUDE, COMPOSITE_CODES
from fpp_nodes.core.phase import wrap_phase
from fpp_nodes.core.scenes import SURFACE_DEPTH_MM
from fpp_nodes.core.simulation import Rig

DESIGNS = {  # (orders K, row period P) per code, fine to coarse
    "shipped": COMPOSITE_CODES,
    "+ (216, 48)": (*COMPOSITE_CODES, (216, 48.0)),
    "+ (216, 192)": (*COMPOSITE_CODES, (216, 192.0)),
    "+ (180, 96)": (*COMPOSITE_CODES, (180, 96.0)),
}
BANDS_MM = ((500, 950), (1450, 2000), (2000, 3000), (3000, 6000), (6000, 50000))
GRID_PX = 16


def main() -> None:
    rig = Rig()
    patterns = rig.pattern_set()
    cam = rig.camera()
    v, u = np.mgrid[GRID_PX // 2 : cam.height : GRID_PX, GRID_PX // 2 : cam.width : GRID_PX].astype(np.float64)
    rays = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], -1).reshape(-1, 1, 3)

    def seen(depths):  # projector (x, y) at each grid pixel (rows) and depth (columns)
        x, y, _ = rig.to_projector(rays * depths[None, :, None])
        return x, y

    near, far = SURFACE_DEPTH_MM
    inside = seen(np.linspace(near, far, 3501))  # fine enough to interpolate each code along the carrier
    outside_mm = np.concatenate([np.geomspace(500, near - 50, 150), np.geomspace(far + 100, 50000, 400)])
    outside = seen(outside_mm)
    top = patterns.frequencies[-1]

    def phases(design, x, y):  # the carrier's, then each code's
        carrier = 2 * np.pi * top * x / patterns.width
        return carrier, [carrier / k + 2 * np.pi * y / p for k, p in design]

    print(f"default rig, working range {near:g}-{far:g} mm; exact codes at pixels every {GRID_PX} px")
    print(f"{'codes':14} {'min_sep':>8} {'closest':>8} {'carrier':>8}   pixels whose codes name an order in the range")
    print(f"{'':14} {'rad':>8} {'rad':>8} {'amp.':>8}   " + "  ".join(f"{f'{a}-{b} mm':>13}" for a, b in BANDS_MM))
    for name, design in DESIGNS.items():
        carrier_in, codes_in = phases(design, *inside)
        carrier_out, codes_out = phases(design, *outside)
        separation, least = np.inf, np.empty((carrier_in.shape[0], outside_mm.size))
        for i in range(carrier_in.shape[0]):
            order = np.argsort(carrier_in[i])  # the carrier phase is monotonic in depth
            along, codes = carrier_in[i][order], [c[i][order] for c in codes_in]
            # every order of the range, and how close two orders' codes come
            orders = along[0] + 2 * np.pi * np.arange(int((along[-1] - along[0]) / (2 * np.pi)) + 1)
            at = [np.interp(orders, along, c) for c in codes]
            gap = np.sqrt(sum(wrap_phase(c[:, None] - c[None, :]) ** 2 for c in at))
            separation = min(separation, float(gap[~np.eye(orders.size, dtype=bool)].min()))
            # each depth outside: the orders of the range with its wrapped carrier phase, and their codes' miss
            start = np.ceil((along[0] - carrier_out[i]) / (2 * np.pi))
            candidates = carrier_out[i][:, None] + 2 * np.pi * (start[:, None] + np.arange(orders.size + 1)[None, :])
            miss = np.sqrt(
                sum(wrap_phase(np.interp(candidates, along, c) - o[i][:, None]) ** 2 for c, o in zip(codes, codes_out))
            )
            least[i] = np.where(candidates <= along[-1], miss, np.inf).min(axis=1)
        share = np.mean(least < separation / 2, axis=0)
        amplitude = 1 / (1 + len(design) * CODE_AMPLITUDE / CARRIER_AMPLITUDE)
        cells = "  ".join(f"{share[(outside_mm >= a) & (outside_mm < b)].mean():13.1%}" for a, b in BANDS_MM)
        print(f"{name:14} {separation:8.2f} {least.min():8.2f} {amplitude:8.2f}   {cells}")


if __name__ == "__main__":
    main()
