"""Which single-shot pattern: the paper's (the first image of the 100-fringe set) against this sensor's
composite (the 100-fringe carrier plus code gratings that tell its order), decoded classically
(Takeda's FTP: the carrier's lobe, and each code's own lobe), on a tilted plane under each condition a
rig meets: dark albedo, texture, defocus, noise, a projector gamma the patterns do not compensate.

Prints per condition: the carrier's wrapped-phase error (RMS, rad and mm of depth) for each pattern,
each code's phase error against the margin (half the closest two orders' codes; training.compare_codes
compares code designs), and the share of pixels whose
fringe order is wrong from each pixel's own code and after the composite decoder's neighbourhood vote (NaN where
unsure). The paper's image has no order to tell: every pixel's order there is a guess.

    python scripts/compare_patterns.py
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from fpp_nodes.core.calibration import Calibration, default_calibration_path
from fpp_nodes.core.patterns import composite_phases
from fpp_nodes.core.phase import ftp_wrapped_phase
from fpp_nodes.core.reconstruct import CompositeDecoder, composite_ftp_phases
from fpp_nodes.core.scenes import plane_scene
from fpp_nodes.core.simulation import Rig, Scene, SceneRenderer, render

from machine import describe

BORDER = 24  # FTP's edge effects are not what is compared here


def conditions(rig: Rig):
    plane = plane_scene(rig, 1150.0, tilt_x_deg=20.0, tilt_y_deg=10.0)
    u, v = np.meshgrid(np.arange(rig.width), np.arange(rig.height))
    checkers = np.where((u // 24 + v // 24) % 2 == 0, 1.0, 0.3)
    yield "reference (albedo 0.9, noise 1, blur 0.5)", rig, plane
    yield "dark (albedo 0.15)", rig, Scene("dark", plane.depth_mm, np.full(plane.depth_mm.shape, 0.15))
    yield "checkers 24 px, contrast 0.3", rig, Scene("checkers", plane.depth_mm, 0.9 * checkers)
    yield "defocus 1.5 px", replace(rig, blur_sigma_px=1.5), plane
    yield "noise 3 counts", replace(rig, noise_sigma=3.0), plane
    yield "projector gamma 2.5, patterns for 2.2", replace(rig, projector_gamma=2.5), plane


def wrapped_error(measured, exact):
    return np.angle(np.exp(1j * (measured - exact)))


def main():
    print(describe({"numpy/opencv": 1}, ("numpy", "cv2")))
    rig = Rig()
    u, v = np.arange(rig.width)[None, :], np.arange(rig.height)[:, None]
    calibration = Calibration.load(default_calibration_path())
    near, far = calibration.working_range_mm
    span = np.abs(np.subtract(*(calibration.model.phase_at_depth(z, u, v) for z in (near, far)))) / (2 * np.pi)
    print(
        f"\nthe working range {near:g}-{far:g} mm spans {span.min():.1f}-{span.max():.1f} "
        "fringe orders of the carrier across the image"
    )
    composite = calibration.patterns
    decoder = CompositeDecoder(calibration)
    base = Rig()
    rows = []
    for name, rig, scene in conditions(base):
        renderer = SceneRenderer(rig, scene)
        xp, yp = renderer.projector_xy
        inner = np.zeros(xp.shape, bool)
        inner[BORDER:-BORDER, BORDER:-BORDER] = renderer.lit[renderer.crop][BORDER:-BORDER, BORDER:-BORDER]
        carrier, *codes = composite_phases(composite, xp, yp)
        images = render(rig, scene, composite, np.random.default_rng(1)).images  # the patterns stay the 2.2 set
        mm_per_rad = np.abs(
            calibration.model.depth_per_radian(carrier, *np.meshgrid(np.arange(rig.width), np.arange(rig.height)))
        )
        paper, _ = ftp_wrapped_phase(images[composite.input_index("paper")])
        phase, code_phases, _ = composite_ftp_phases(images[composite.single_shot_index], calibration)
        row = [name]
        for measured in (paper, phase):
            e = wrapped_error(measured, carrier)[inner]
            row += [np.sqrt(np.mean(e**2)), np.sqrt(np.mean((e * mm_per_rad[inner]) ** 2))]
        row.append([np.sqrt(np.mean(wrapped_error(m, c)[inner] ** 2)) for m, c in zip(code_phases, codes)])
        out = np.stack([f(p) for p in (phase, *code_phases) for f in (np.sin, np.cos)])
        own = decoder.code_phase(phase.astype(np.float32), [c.astype(np.float32) for c in code_phases])
        truth_order = np.rint((carrier - phase) / (2 * np.pi))
        row.append(np.mean((np.rint((own - phase) / (2 * np.pi)) != truth_order)[inner]))
        depth, _ = decoder(out, 0.5)
        given = np.isfinite(depth) & inner
        row += [np.mean(np.abs(depth - scene.depth_mm)[given] > 1.0) if given.any() else 0.0, given.sum() / inner.sum()]
        rows.append(row)
    print(
        f"\nFTP on one image of each pattern, a plane at 1150 mm tilted 20/10 deg; every order decision's margin: "
        f"{decoder.min_separation / 2:.3f} rad (half the closest two orders' codes, root sum of squares over "
        "the codes, this calibration)"
    )
    print(
        f"{'condition':42} {'paper: carrier rad  mm':>22} {'composite: carrier rad  mm':>27} {'codes rad':>12} "
        f"{'own order wrong':>16} {'voted >1mm':>11} {'cover':>6}"
    )
    for name, pr, pmm, cr, cmm, code_rms, own_wrong, voted_wrong, cover in rows:
        code_rms = " ".join(f"{c:.3f}" for c in code_rms)
        print(
            f"{name:42} {pr:15.3f} {pmm:6.2f} {cr:20.3f} {cmm:6.2f} {code_rms:>12} {own_wrong:16.1%} "
            f"{voted_wrong:11.2%} {cover:6.1%}"
        )
    print(
        "paper: its image carries no fringe order (every order a guess); composite: the order from the code, "
        "per pixel and after the decoder's votes (NaN where unsure, min_confidence 0.5)"
    )


if __name__ == "__main__":
    main()
