from dataclasses import replace

import numpy as np
import pytest
import yaml

from fpp_nodes.core.calibration import Calibration, CalibrationError, RationalModel, back_project, pixel_grid
from fpp_nodes.core.phase import PhaseError
from fpp_nodes.core.reconstruct import CompositeDecoder, reconstruct_ftp
from fpp_nodes.core.scenes import SURFACE_DEPTH_MM, plane_scene
from fpp_nodes.core.simulation import Rig, SceneRenderer, render
from fpp_nodes.core.workflow import calibrate_from_planes


def test_rig_model_maps_phase_back_to_depth(ideal_rig, ideal_patterns):
    model = ideal_rig.true_model(ideal_patterns)
    u, v = pixel_grid((ideal_rig.height, ideal_rig.width))
    for z in (1100.0, 1200.0, 1290.0):
        phase = model.phase_at_depth(z, u, v)
        np.testing.assert_allclose(model.depth(phase, u, v), z, rtol=1e-12)
    capture = render(ideal_rig, plane_scene(ideal_rig, 1150.0), ideal_patterns)
    expected = 2 * np.pi * 100 * capture.projector_coord / ideal_patterns.width
    np.testing.assert_allclose(model.phase_at_depth(1150.0, u, v), expected, atol=1e-9)


def test_calibration_from_noise_free_planes_recovers_the_rendering_coefficients(ideal_rig, ideal_patterns):
    stacks = [
        render(ideal_rig, plane_scene(ideal_rig, z), ideal_patterns).images for z in (1100, 1150, 1200, 1250, 1300)
    ]
    calibration, residuals = calibrate_from_planes(
        stacks, [1100, 1150, 1200, 1250, 1300], ideal_rig.camera(), ideal_patterns
    )
    true = ideal_rig.true_model(ideal_patterns)
    fitted = calibration.model
    # compare every term at its largest value in the image, relative to the whole numerator/denominator;
    # what is left is the pixelated projector's interpolation ripple (about 1e-3 rad of phase)
    u, v = 639.0, 479.0
    phi = 2 * np.pi * 100
    size = np.abs([1, phi, u, u * phi, v, v * phi, u * u, u * u * phi, v * v, v * v * phi, u * v, u * v * phi])
    assert np.max(np.abs(fitted.c - true.c) * size) < 3e-5 * np.sum(np.abs(true.c) * size)
    assert np.max(np.abs(fitted.d - true.d) * size) < 3e-5 * np.sum(np.abs(true.d) * size)
    assert max(residuals) < 5e-3  # mm: the interpolation ripple, nothing else
    assert calibration.working_range_mm == (1100.0, 1300.0)  # the planes' depths


def test_calibration_of_the_noisy_rig_predicts_depth_to_micrometres(rig, patterns, calibration):
    true = rig.true_model(patterns)
    u, v = pixel_grid((rig.height, rig.width))
    for z in (1080.0, 1200.0, 1320.0):  # inside and a little beyond the calibrated planes
        assert np.abs(calibration.model.depth(true.phase_at_depth(z, u, v), u, v) - z).max() < 0.02


def test_calibration_file_round_trips(calibration, tmp_path):
    path = tmp_path / "cal.yaml"
    calibration.save(path)
    loaded = Calibration.load(path)
    np.testing.assert_array_equal(loaded.model.c, calibration.model.c)
    np.testing.assert_array_equal(loaded.model.d, calibration.model.d)
    assert loaded.patterns == calibration.patterns and loaded.camera == calibration.camera
    assert loaded.working_range_mm == calibration.working_range_mm == (1000.0, 1350.0)
    assert yaml.safe_load(path.read_text())["version"] == 1
    assert "distortion" not in yaml.safe_load(path.read_text())["camera"]  # files without a lens stay as they were
    lens = replace(calibration, camera=replace(calibration.camera, distortion=(-0.9, 0.1, 1e-4, -2e-4, 0.0)))
    lens.save(path)
    assert Calibration.load(path).camera == lens.camera
    assert "bits" not in yaml.safe_load(path.read_text())["camera"]
    twelve = replace(calibration, camera=replace(calibration.camera, bits=12))
    twelve.save(path)
    assert Calibration.load(path).camera == twelve.camera and Calibration.load(path).camera.bits == 12


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda d: d.pop("model"), "missing model"),
        (lambda d: d["camera"].pop("fx"), "missing 'fx'"),
        (lambda d: d.update(version=99), "version 99"),
        (lambda d: d.update(format="something"), "not a calibration file"),
        (lambda d: d["model"].update(c=[1.0, 2.0]), "12 \\+ 12"),
        (lambda d: d["model"]["d"].__setitem__(3, "x"), "malformed"),
        (lambda d: d["patterns"].update(steps=2), "steps must be >= 3"),
        (lambda d: d["camera"].update(fx=-5), "focal lengths"),
        (lambda d: d["camera"].update(distortion=[0.1, 0.2]), "distortion must be 5 finite numbers"),
        (lambda d: d["camera"].update(bits=20), "camera bits must be a whole number 1-16"),
        (lambda d: d["camera"].update(bits=12.5), "camera bits must be a whole number 1-16"),
        (lambda d: d.update(working_range_mm=[1350.0, 1000.0]), "0 < near < far"),
        (lambda d: d.update(working_range_mm=[1000.0]), "must be \\[near, far\\]"),
    ],
)
def test_malformed_calibration_files_are_clear_errors(calibration, tmp_path, edit, message):
    data = calibration.to_dict()
    edit(data)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(CalibrationError, match=message):
        Calibration.load(path)


def test_unreadable_calibration_files_are_clear_errors(tmp_path):
    with pytest.raises(CalibrationError, match="cannot read"):
        Calibration.load(tmp_path / "missing.yaml")
    (tmp_path / "bad.yaml").write_text("camera: [unclosed")
    with pytest.raises(CalibrationError, match="not valid YAML"):
        Calibration.load(tmp_path / "bad.yaml")
    (tmp_path / "list.yaml").write_text("- 1\n- 2\n")
    with pytest.raises(CalibrationError, match="not a YAML mapping"):
        Calibration.load(tmp_path / "list.yaml")


def test_model_refuses_wrong_coefficients():
    with pytest.raises(CalibrationError, match="c0 must be 1"):
        RationalModel(np.r_[2.0, np.zeros(11)], np.ones(12))
    with pytest.raises(CalibrationError, match="finite"):
        RationalModel(np.r_[1.0, np.full(11, np.nan)], np.ones(12))


def test_back_projection_follows_the_optical_frame(calibration):
    cam = calibration.camera
    depth = np.full((cam.height, cam.width), 1000.0, np.float32)
    depth[0, 0] = np.nan
    xyz = back_project(depth, cam)
    assert np.isnan(xyz[0, 0]).all()
    np.testing.assert_allclose(
        xyz[-1, -1],
        [1000 * (cam.width - 1 - cam.cx) / cam.fx, 1000 * (cam.height - 1 - cam.cy) / cam.fy, 1000],
        rtol=1e-6,
    )
    assert xyz[240, 639, 0] > 0 and xyz[479, 320, 1] > 0  # x right, y down


def test_the_shipped_calibration_is_what_fpp_demo_makes(rig, patterns):
    """The shipped file is the seed-0 fit. Coefficients of a least-squares fit move with the BLAS build
    (small terms by 0.2% relative), so compare what matters: the depth both give over the working
    volume, to 1e-4 mm (240x under the sensor's 0.024 mm noise). Another noise seed moves it 1.2e-3 mm."""
    from fpp_nodes.core.calibration import default_calibration_path
    from fpp_nodes.core.workflow import simulated_calibration

    shipped = Calibration.load(default_calibration_path())
    made, _ = simulated_calibration(rig, patterns, seed=0)
    assert shipped.patterns == made.patterns and shipped.camera == made.camera
    assert shipped.working_range_mm == made.working_range_mm == SURFACE_DEPTH_MM
    true = rig.true_model(patterns)
    u, v = pixel_grid((rig.height, rig.width))
    for z in np.linspace(1050.0, 1350.0, 7):
        phase = true.phase_at_depth(z, u, v)
        difference = made.model.depth(phase, u, v) - shipped.model.depth(phase, u, v)
        assert np.abs(difference).max() < 1e-4, (z, np.abs(difference).max())


def test_a_camera_that_sees_the_projectors_side_edges_calibrates(patterns):
    """A projector whose light does not fill the view (220 -> 170 mm wide): at its first and last
    columns every frequency's phase is the same, so where noise carries the lowest one across its wrap
    the order is a whole turn (100 orders) off. Pixels within 5 sigma of the wrap are dropped, and the
    fit from noisy planes holds to 0.03 mm RMS on every plane (measured 0.014-0.017 mm; before,
    24-29000 mm)."""
    from fpp_nodes.core.simulation import Rig
    from fpp_nodes.core.workflow import simulated_calibration

    rig = replace(Rig(), projector_field_mm=170.0)
    planes = (1140.0, 1170.0, 1200.0, 1230.0, 1260.0)
    calibration, residuals = simulated_calibration(rig, patterns, 1, planes, working_range_mm=None)
    assert max(residuals) < 0.03, residuals
    # the composite's codes too: FTP read the coarse one 1.8 rad off beside the light's edges, the decoder's
    # margin shrank to 0.001 rad and it said NaN everywhere; with the unlit pixels evened out it is the
    # default rig's (measured 0.943 rad, the codes' fit 0.002 rad)
    decoder = CompositeDecoder(calibration)
    assert decoder.min_separation > 0.9 and decoder.row_fit_error < 0.01


def test_a_cameras_bits_widen_its_frames_to_full_scale(calibration):
    twelve = replace(calibration.camera, bits=12)
    values = np.arange(4096, dtype=np.uint16)
    wide = twelve.full_range(values)
    assert wide.dtype == np.uint16 and wide[0] == 0 and wide[-1] == 65535  # saturation stays saturation
    assert np.all(np.diff(wide.astype(int)) > 0)
    assert np.abs(wide - values * (65535 / 4095)).max() < 1.0  # linear to within a count of 65535
    frame = np.full((4, 4), 200, np.uint8)
    assert calibration.camera.full_range(frame) is frame  # bits not said: the frame as it came
    assert replace(calibration.camera, bits=8).full_range(frame) is frame
    with pytest.raises(CalibrationError, match="value of 5000, more than the 4095"):  # widened twice, or another camera
        twelve.full_range(np.array([[5000]], np.uint16))
    with pytest.raises(CalibrationError, match="do not fit uint8"):
        twelve.full_range(frame)


def test_a_12_bit_camera_in_mono16_frames_measures_as_a_16_bit_one(calibration):
    """A camera driver that sends 12-bit pixels as mono16 (values up to 4095): said in the calibration,
    its frames measure as the same rig's 16-bit frames, saturation refused on both paths; not said, the
    multi-shot path takes clipped fringes for good ones, and the frames are said to be narrow."""
    from fpp_nodes.core.model import DepthModel, default_model_path
    from fpp_nodes.core.reconstruct import PspReconstructor
    from fpp_nodes.core.scenes import make_scene
    from fpp_nodes.core.simulation import Rig

    rig = Rig(camera_bit_depth=16, noise_sigma=16.0, gain=1.2)  # bright: a fifth of the fringes clip
    capture = render(rig, make_scene(rig, "sculpture", 3), rig.pattern_set(), np.random.default_rng(1))
    lit, narrow = capture.valid, (capture.images >> 4).astype(np.uint16)
    clipped = lit & (capture.images[12:16] >= 65535).any(0)  # the highest frequency's fringes
    assert 0.1 < clipped.sum() / lit.sum() < 0.3
    twelve = replace(calibration, camera=replace(calibration.camera, bits=12))

    def measured(cal, images):
        multi = PspReconstructor(cal)(images).depth_mm
        single = DepthModel(default_model_path(), calibration=cal)(images[cal.patterns.single_shot_index])
        return [
            (np.isfinite(d[lit]).mean(), np.sqrt(np.nanmean((d - capture.depth_mm)[lit] ** 2))) for d in (multi, single)
        ]

    wide, said = measured(calibration, capture.images), measured(twelve, narrow)
    for (cover, rmse), (cover_12, rmse_12) in zip(wide, said):
        assert abs(cover_12 - cover) < 0.01 and abs(rmse_12 - rmse) < 0.1 * rmse, (wide, said)
    assert np.isnan(PspReconstructor(twelve)(narrow).depth_mm[clipped]).all()
    assert np.isfinite(PspReconstructor(calibration)(narrow).depth_mm[clipped]).mean() > 0.9  # 65535 never comes
    assert "a 12-bit camera?" in calibration.camera.narrow_hint(narrow)
    assert twelve.camera.narrow_hint(narrow) is None and calibration.camera.narrow_hint(capture.images) is None


def test_planes_of_a_12_bit_camera_calibrate_as_a_16_bit_ones(calibration):
    from fpp_nodes.core.simulation import Rig

    rig, depths = Rig(camera_bit_depth=16, noise_sigma=16.0), (1100, 1150, 1200, 1250, 1300)
    patterns = rig.pattern_set()
    stacks = [render(rig, plane_scene(rig, z), patterns, np.random.default_rng(z)).images for z in depths]
    wide, _ = calibrate_from_planes(stacks, depths, rig.camera(), patterns)
    twelve = replace(rig.camera(), bits=12)
    narrow, _ = calibrate_from_planes([(s >> 4).astype(np.uint16) for s in stacks], depths, twelve, patterns)
    assert narrow.camera.bits == 12  # the file says so to every node that reads it
    u, v = pixel_grid((rig.height, rig.width))
    phase = wide.model.phase_at_depth(1200.0, u, v)
    assert np.abs(narrow.model.depth(phase, u, v) - 1200.0).max() < 0.01  # mm


def test_a_composite_frame_that_does_not_fit_its_plane_is_refused(rig, patterns):
    """A plane's composite frame taken 2 rows off the rest of its sequence (the camera or plate moved, a
    frame from elsewhere): its code gratings' row phases no longer fit one model with the other planes
    (0.48 rad RMS measured, against 0.01-0.02 rad from good planes), which would move the decoder's
    orders by most of their 0.47 rad margin: a clear error, not a calibration that decodes wrong orders."""
    rng = np.random.default_rng(7)
    depths = [1100.0, 1150.0, 1200.0, 1250.0, 1300.0]
    stacks = [render(rig, plane_scene(rig, z), patterns, rng).images for z in depths]
    calibrate_from_planes(stacks, depths, rig.camera(), patterns)  # these planes calibrate
    composite = stacks[2][patterns.single_shot_index]
    stacks[2][patterns.single_shot_index] = np.roll(composite, 2, axis=0)
    with pytest.raises(CalibrationError, match="code gratings fit their model on the planes to 0.4"):
        calibrate_from_planes(stacks, depths, rig.camera(), patterns)


def test_a_plane_with_a_dark_spot_calibrates_the_codes_as_a_clean_one(rig, patterns, calibration):
    """A 60 x 60 px spot of albedo 0.02 on one of five planes: FTP cannot read the codes there, and the
    unwrapping leaves a region around it a whole turn off (10% of the code's samples; fitted as they
    came, the model missed them by 1.2 rad RMS and the decoder's orders were lost). Taken back a turn,
    they fit, and the decoder's margin and fit are the clean planes' (measured: 0.942 rad, 0.0014 rad)."""
    rng = np.random.default_rng(7)
    depths = [1100.0, 1150.0, 1200.0, 1250.0, 1300.0]
    stacks = []
    for z in depths:
        scene = plane_scene(rig, z)
        if z == 1200.0:
            albedo = np.broadcast_to(scene.albedo, scene.depth_mm.shape).copy()
            albedo[200:260, 300:360] = 0.02
            scene = replace(scene, albedo=albedo)
        stacks.append(render(rig, scene, patterns, rng).images)
    spotted = CompositeDecoder(calibrate_from_planes(stacks, depths, rig.camera(), patterns)[0])
    clean = CompositeDecoder(calibration)
    assert abs(spotted.min_separation - clean.min_separation) < 0.01 and spotted.row_fit_error < 0.01


def test_a_projector_off_the_cameras_axis_calibrates_from_planes_and_measures_or_says_why_not():
    """A projector 20 mm below the camera's axis moves the rows a camera pixel sees by 20 px over the
    planes' 200 mm, half a turn of the fine code from one plane to the next: taking the first plane's
    turn for every plane refused the calibration; each plane's rows now follow where the planes before
    say they are heading (workflow.aligned_rows), and the models hold the true rows to 0.01 rad. Its codes
    come closer (0.31 rad against 0.93: the decoder's margin is half that), and the shipped network gives
    a scene of separate objects 83.1% of its lit pixels, none off by more than 1 mm. A projector rolled 3
    degrees makes the coarse code stand still from order to order, so two orders of the range show the
    same codes: the decoder says so rather than decode nothing (every pixel was NaN, with a range warning)."""
    from fpp_nodes.core.model import DepthModel, default_model_path
    from fpp_nodes.core.scenes import make_scene
    from fpp_nodes.core.workflow import CALIBRATION_DEPTHS_MM

    for rig, works in ((Rig(projector_below_mm=20.0), True), (Rig(projector_roll_deg=3.0), False)):
        patterns, rng = rig.pattern_set(), np.random.default_rng(7)
        planes = [render(rig, plane_scene(rig, z), patterns, rng).images for z in CALIBRATION_DEPTHS_MM]
        calibration, _ = calibrate_from_planes(
            planes, list(CALIBRATION_DEPTHS_MM), rig.camera(), patterns, working_range_mm=SURFACE_DEPTH_MM
        )
        if not works:
            with pytest.raises(PhaseError, match="come within .* rad of each other"):
                CompositeDecoder(calibration)
            continue
        u, v = rig.camera().ideal_pixels()
        for z in (1125.0, 1275.0):  # between the planes
            seen = SceneRenderer(rig, plane_scene(rig, z)).projector_xy[1]
            for i, (_, fy) in enumerate(patterns.code_frequencies):
                error = calibration.code_row_phase_at_depth(i, z, u, v) - 2 * np.pi * fy * seen / patterns.height
                assert np.abs(np.angle(np.exp(1j * error))).max() < 0.02
        capture = render(rig, make_scene(rig, "objects", 5), patterns, np.random.default_rng(5))
        truth = np.where(capture.valid, capture.depth_mm, np.nan)
        depth, _ = DepthModel(default_model_path(), threads=2, calibration=calibration).infer(capture.images[-1])
        given = np.isfinite(depth) & np.isfinite(truth)
        assert given.sum() / np.isfinite(truth).sum() > 0.8
        assert np.mean(np.abs(depth - truth)[given] > 1.0) < 0.002


def test_a_projector_above_the_camera_calibrates_from_planes_and_measures():
    """A projector 200 mm above the camera (no sideways baseline) measures with horizontal fringes and the
    composite with them (refused before 2026-12-05). Its 800 rows across the field make the fringes finer
    than the default rig's (5.7 px in the camera against 9.2: the network reads the frames resampled, and
    transposed), so the working range is 1100-1300 mm (1000-1350 spans 45 orders, more than the code tells
    apart). Multi-shot: 0.016 mm RMSE on a scene of separate objects; the shipped network: 91.9% of its lit
    pixels, none off by more than 1 mm."""
    from fpp_nodes.core.metrics import depth_errors
    from fpp_nodes.core.model import DepthModel, default_model_path
    from fpp_nodes.core.reconstruct import PspReconstructor
    from fpp_nodes.core.scenes import make_scene
    from fpp_nodes.core.workflow import CALIBRATION_DEPTHS_MM, fringe_depth_mm

    rig = Rig(baseline_mm=0.0, projector_below_mm=-200.0)
    patterns, rng = rig.pattern_set(orientation="horizontal"), np.random.default_rng(7)
    planes = [render(rig, plane_scene(rig, z), patterns, rng).images for z in CALIBRATION_DEPTHS_MM]
    calibration, _ = calibrate_from_planes(
        planes, list(CALIBRATION_DEPTHS_MM), rig.camera(), patterns, working_range_mm=(1100.0, 1300.0)
    )
    capture = render(rig, make_scene(rig, "objects", 5), patterns, np.random.default_rng(5))
    rec = PspReconstructor(calibration)(capture.images)
    e = depth_errors(rec.depth_mm, capture.depth_mm, capture.valid, fringe_depth_mm(calibration, rec.phase))
    assert e.order_errors == 0 and e.coverage > 0.95 and e.rmse_mm < 0.03, e
    model = DepthModel(default_model_path(), threads=2, calibration=calibration)
    assert model.layout.transposed and model.scale > 1.5
    truth = np.where(capture.valid, capture.depth_mm, np.nan)
    depth, _ = model.infer(capture.images[-1])
    given = np.isfinite(depth) & np.isfinite(truth)
    assert given.sum() / np.isfinite(truth).sum() > 0.9
    assert np.mean(np.abs(depth - truth)[given] > 1.0) < 0.002


@pytest.mark.parametrize("roll_deg, least", [(5.0, 0.9), (20.0, 0.84)])
def test_a_camera_rolled_about_its_axis_calibrates_from_planes_and_measures(rig, patterns, roll_deg, least):
    """A camera mounted rolled about its axis (here every rendered image turned about the centre, which
    also smooths it a little): the code gratings' spectral lobes are told from the carrier's by
    direction, and each plane's row phase is continued into its unlit corners as a ramp, so the planes
    calibrate (both refused 5 degrees before: the carrier's lobe, 6 cycles down, taken for a code; the
    fine code unwrapped 40% of a plane a turn off). The shipped network is shown the frames turned
    upright (model.network_layout; before, they were shown tilted: at 5 degrees 88.1% of a scene of
    separate objects' lit pixels given, at 20 none): 91.6 and 85.8%, 0.02% off by more than 1 mm
    (unrolled: 93.5%, 0.01%)."""
    import cv2

    from fpp_nodes.core.model import DepthModel, default_model_path
    from fpp_nodes.core.scenes import make_scene
    from fpp_nodes.core.workflow import CALIBRATION_DEPTHS_MM

    def rolled(stack):
        h, w = stack.shape[-2:]
        turn = cv2.getRotationMatrix2D(((w - 1) / 2, (h - 1) / 2), roll_deg, 1.0)
        return np.stack([cv2.warpAffine(image, turn, (w, h), flags=cv2.INTER_LINEAR) for image in stack])

    rng = np.random.default_rng(7)
    planes = [rolled(render(rig, plane_scene(rig, z), patterns, rng).images) for z in CALIBRATION_DEPTHS_MM]
    calibration, _ = calibrate_from_planes(
        planes, list(CALIBRATION_DEPTHS_MM), rig.camera(), patterns, working_range_mm=SURFACE_DEPTH_MM
    )
    capture = render(rig, make_scene(rig, "objects", 5), patterns, np.random.default_rng(5))
    truth = rolled(np.where(capture.valid, capture.depth_mm, 0).astype(np.float32)[None])[0]
    lit = rolled(capture.valid.astype(np.float32)[None])[0] > 0.999
    model = DepthModel(default_model_path(), threads=2, calibration=calibration)
    assert model.layout.turned_deg == pytest.approx(-roll_deg, abs=0.1)
    depth, _ = model.infer(rolled(capture.images[-1:])[0])
    given = np.isfinite(depth) & lit
    inner = cv2.erode(lit.view(np.uint8), np.ones((5, 5), np.uint8)).view(bool)  # the turned truth is exact there
    assert given.sum() / lit.sum() > least
    assert np.mean(np.abs(depth - truth)[given & inner] > 1.0) < 0.005


def test_a_rig_that_moved_since_its_calibration_is_told_from_one_sequence(rig, patterns, calibration):
    """reconstruct.CodeFit: as calibrated, a composite frame's codes fit the calibration's code models at the
    multi-shot depth; a projector rolled 0.3 degree since misses them by more than MAX_CODE_MISFIT_RAD, its
    multi-shot depth nearly a millimetre off and nothing in it to say so, and so does one rolled 0.1 degree
    (measured 0.25 rad against 0.2; depth 0.3 mm off; the median miss, before, saw nothing under 0.2 degree); one
    moved 2 mm along the baseline is not seen (its depth 0.1 mm off)."""
    from fpp_nodes.core.reconstruct import MAX_CODE_MISFIT_RAD, CodeFit, PspReconstructor
    from fpp_nodes.core.scenes import make_scene

    fit, psp = CodeFit(calibration), PspReconstructor(calibration)

    def misfit_and_error(moved):
        capture = render(moved, make_scene(moved, "objects", 5), patterns, np.random.default_rng(5))
        rec = psp(capture.images)
        error = np.nanmedian(np.abs(rec.depth_mm - capture.depth_mm)[capture.valid])
        return fit(capture.images[-1], rec.depth_mm, rec.phase), error

    knocks = (rig, Rig(projector_roll_deg=0.3), Rig(projector_roll_deg=0.1), Rig(baseline_mm=rig.baseline_mm + 2))
    as_calibrated, rolled, rolled_less, along = (misfit_and_error(moved) for moved in knocks)
    assert as_calibrated[0] < 0.05 and as_calibrated[1] < 0.03, as_calibrated
    assert rolled[0] > MAX_CODE_MISFIT_RAD and rolled[1] > 0.5, rolled
    assert rolled_less[0] > MAX_CODE_MISFIT_RAD and rolled_less[1] > 0.2, rolled_less
    assert along[0] < 0.05 and along[1] > 0.05, along


# how the camera's frames are turned from the simulator's (np.rot90's quarter turns, then mirrored along axes), and
# the Layout that shows them to the network as training did
TURNS = {
    "left-right (rear mode)": (0, (1,), (False, (1,))),
    "both (ceiling mode)": (0, (0, 1), (False, (0, 1))),
    "portrait, a quarter turn anticlockwise": (1, (), (True, (1,))),
    "portrait, a quarter turn clockwise, in rear mode": (3, (1,), (True, ())),
}


@pytest.mark.parametrize("quarters, mirrored, layout", TURNS.values(), ids=TURNS.keys())
def test_a_projector_showing_its_image_mirrored_or_a_portrait_camera_calibrates_and_measures(
    rig, patterns, quarters, mirrored, layout
):
    """A projector in rear or ceiling mode (its image mirrored), and a camera mounted turned a quarter
    (portrait: a rig whose camera is 480 wide and 640 tall, every rendered image turned, so the camera's
    640x480 frames show the fringes running along its columns). The plane calibration takes the code
    lobes that lie across the carrier's fringes, each whose phase runs with the carrier's (ceiling mode and
    both portrait mounts were refused: FTP read each code's mirror lobe, or the carrier's lobe as a code),
    and the network is shown the fringes turned back as training showed them (model.network_layout; it
    read a mirrored carrier backwards, every pixel NaN and no warning). The shipped network then
    measures the scene of separate objects as on the rig as simulated: mirrored, 93.5% of the lit pixels
    0.01% off by more than 1 mm; portrait, 90.3-91.0% at 0.00% (the same rig upright: 91.0%; 0.7 point
    fewer one way round: the decisions' margin, CompositeDecoder.min_separation, is the least over a
    grid of pixels that meets the image's other edge then)."""
    from fpp_nodes.core.model import DepthModel, Layout, default_model_path
    from fpp_nodes.core.scenes import make_scene
    from fpp_nodes.core.simulation import Rig
    from fpp_nodes.core.workflow import CALIBRATION_DEPTHS_MM

    simulated = rig if quarters == 0 else Rig(width=rig.height, height=rig.width)

    def turned(images):
        return np.ascontiguousarray(np.flip(np.rot90(images, quarters, axes=(-2, -1)), [a - 2 for a in mirrored]))

    rng = np.random.default_rng(7)
    planes = [turned(render(simulated, plane_scene(simulated, z), patterns, rng).images) for z in CALIBRATION_DEPTHS_MM]
    calibration, _ = calibrate_from_planes(
        planes, list(CALIBRATION_DEPTHS_MM), rig.camera(), patterns, working_range_mm=SURFACE_DEPTH_MM
    )
    model = DepthModel(default_model_path(), threads=2, calibration=calibration)
    assert model.layout == Layout(*layout)
    capture = render(simulated, make_scene(simulated, "objects", 5), patterns, np.random.default_rng(5))
    truth = turned(np.where(capture.valid, capture.depth_mm, np.nan))
    depth, _ = model.infer(turned(capture.images[-1]))
    given = np.isfinite(depth) & np.isfinite(truth)
    assert given.sum() / np.isfinite(truth).sum() > (0.92 if quarters == 0 else 0.89)
    assert np.mean(np.abs(depth - truth)[given] > 1.0) < 0.002
    # the FTP baseline (fpp reconstruct --method ftp) reads the carrier's lobe across whichever axis it runs, and a
    # falling one's (mirrored) too, as on the rig unturned: 89.3-90.2% of the lit pixels with 0.9-1.1% off by more
    # than 1 mm (the default rig unturned: 90.2%, 1.1%), portrait 80.5-81.4%, 0.01-0.02%
    depth = reconstruct_ftp(turned(capture.images[-1]), calibration, decoder=CompositeDecoder(calibration)).depth_mm
    given = np.isfinite(depth) & np.isfinite(truth)
    assert given.sum() / np.isfinite(truth).sum() > (0.87 if quarters == 0 else 0.78)
    assert np.mean(np.abs(depth - truth)[given] > 1.0) < 0.015
