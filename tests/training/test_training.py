"""The single-shot training chain on a tiny data set: data, networks, training, resume, safe
checkpoints, torchrun with two CPU processes, ONNX export and parity, the model in onnxruntime."""

import pickle
import subprocess
import sys
from dataclasses import replace
from itertools import combinations
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from fpp_nodes.core.calibration import Calibration, default_calibration_path
from fpp_nodes.core.fused import pixel_shuffle
from fpp_nodes.core.model import TRAINING_LAYOUT, DepthModel, Layout, ModelError, default_model_path, network_input
from fpp_nodes.core.patterns import COMPOSITE_CODES
from fpp_nodes.core.phase import wrap_phase
from fpp_nodes.core.reconstruct import CompositeDecoder, PspReconstructor
from fpp_nodes.core.scenes import make_scene
from fpp_nodes.core.simulation import Rig, render
from training.compare_codes import DESIGNS, margin, third_margin
from training.dataset import (
    HARD_CONDITIONS,
    SETS,
    SPLITS,
    load_phase_targets,
    load_sample,
    phase_targets,
    sample_family,
    seed_of,
    split_files,
    write_set,
)
from training.evaluate import ALL_FAMILIES, REFUSAL_STEPS, exact_outputs, family_table, main_surface, refusal_table
from training.export import (
    CONFIDENCE_GRID,
    FLOOR_GRID,
    MARGIN_GRID,
    OUTSIDE_GRID,
    OUTSIDE_REFUSAL_BUDGET,
    ROUGHNESS_GRID,
    RULES,
    SIDEBAND_GRID,
    SIDEBAND_REFUSAL_BUDGET,
    SILENT_ERROR_BUDGET,
    SILENT_ERROR_LIMIT,
    SURFACE_GRID,
    WRONG_ORDER_BUDGET,
    Strided,
    choose_again,
    export,
    rule_name,
    sha256,
)
from training.models import CompositeNet, LaidOut, Separable, build, layer_counts, pad_to_stride
from training.train import (
    REFUSED_AMPLITUDE,
    VALIDATION_BATCH,
    FringeDepthSet,
    TrainConfig,
    composite_loss,
    defocused,
    evaluate,
    load_checkpoint,
    load_initial_weights,
    model_from_checkpoint,
    train,
)


@pytest.fixture(scope="module")
def tiny_set(tmp_path_factory):
    return write_set(tmp_path_factory.mktemp("data"), "single", counts=(3, 1, 1), workers=1)


@pytest.fixture(scope="module")
def trained(tiny_set, tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    cfg = TrainConfig(data=str(tiny_set), out=str(out), arch="unet", width=4, epochs=1, depth_offset_mm=1150.0)
    train(cfg)
    return out, cfg


def test_a_sample_of_an_earlier_format_is_a_clear_error(tmp_path):
    """Format 2 stored depth as uint16 (mm - 1000) * 100, so 1000-1655 mm only: a set made so is made again."""
    path = tmp_path / "old.npz"
    np.savez_compressed(path, input=np.zeros((4, 4), np.uint8), label=np.zeros((4, 4), np.uint16), truth=0)
    with pytest.raises(ValueError, match="earlier version of training.dataset"):
        load_sample(path)


def test_samples_pair_one_fringe_image_with_its_multi_shot_label(tiny_set):
    files = split_files(tiny_set, "train")
    assert len(files) == 3 and len(split_files(tiny_set, "test")) == 1
    image, label, truth = load_sample(files[0])
    assert image.shape == (480, 640) and image.dtype == np.uint8
    ok = np.isfinite(label) & np.isfinite(truth)
    assert ok.mean() > 0.9 and np.sqrt(np.mean((label - truth)[ok] ** 2)) < 0.06  # the multi-shot label is good
    assert yaml.safe_load((tiny_set / "dataset.yaml").read_text())["counts"] == {"train": 3, "val": 1, "test": 1}


def test_the_validation_loss_does_not_depend_on_the_training_batch(tiny_set, tmp_path):
    """A mean of per-batch means taken at the training batch made a GPU run's validation loss (batch 32)
    incomparable with the CPU recipes' (batch 8): validation takes VALIDATION_BATCH whatever the
    training batch, each batch weighed by its scenes. Two validation scenes, one with most of its label
    untrusted and the rest 40 mm off, so that the batching moves the loss."""
    data = tmp_path / "set"
    (data / "train").mkdir(parents=True)
    (data / "val").mkdir()
    (data / "dataset.yaml").write_text((tiny_set / "dataset.yaml").read_text())
    (data / "train" / "a.npz").write_bytes(split_files(tiny_set, "train")[0].read_bytes())
    (data / "val" / "a.npz").write_bytes(split_files(tiny_set, "val")[0].read_bytes())
    with np.load(split_files(tiny_set, "test")[0]) as z:
        sample = dict(z)
    sample["label"][: 3 * len(sample["label"]) // 4] = np.nan
    sample["label"] += 40.0
    np.savez_compressed(data / "val" / "b.npz", **sample)
    cfg = TrainConfig(data=str(data), out=str(tmp_path / "run"), arch="unet", width=4, epochs=1, batch_size=1)
    last = train(replace(cfg, depth_offset_mm=1150.0))
    model, cfg = model_from_checkpoint(load_checkpoint(tmp_path / "run" / "best.pt"))
    val_set = FringeDepthSet(split_files(data, "val"), cfg.downsample)
    together, one_by_one = (
        evaluate(model, torch.utils.data.DataLoader(val_set, n), torch.device("cpu"))["loss"]
        for n in (VALIDATION_BATCH, 1)
    )
    assert last["val_loss"] == pytest.approx(together, rel=1e-5)
    assert abs(one_by_one - together) > 0.01 * together  # the batching does move it on this set
    # a short last batch weighs by its scenes: eight copies of a, then b alone, is (8 a + b) / 9 (a mean of
    # the two batches' means would be (a + b) / 2)
    a, b = (torch.utils.data.Subset(val_set, [i]) for i in (0, 1))
    loss_a, loss_b = (evaluate(model, torch.utils.data.DataLoader(s, 1), torch.device("cpu"))["loss"] for s in (a, b))
    nine = torch.utils.data.ConcatDataset([a] * VALIDATION_BATCH + [b])
    loss = evaluate(model, torch.utils.data.DataLoader(nine, VALIDATION_BATCH), torch.device("cpu"))["loss"]
    assert loss == pytest.approx((VALIDATION_BATCH * loss_a + loss_b) / (VALIDATION_BATCH + 1), rel=1e-4)


def test_no_two_sets_share_a_scene_but_the_pattern_comparison():
    """Held out means held out: each set's scenes (seeds) are its own, a retest draws new ones; only
    composite_paper renders composite's scenes, to compare the patterns on them."""
    seeds = {
        name: {seed_of(name, split, i) for split, n in zip(SPLITS, SETS[name][1]) for i in range(n)} for name in SETS
    }
    for a, b in combinations(SETS, 2):
        if {a, b} != {"composite", "composite_paper"}:
            assert not seeds[a] & seeds[b], (a, b)
    assert seeds["composite"] == seeds["composite_paper"]


def test_a_set_of_one_family_keeps_the_composite_targets(tmp_path):
    """composite_reliefs holds one family (reliefs) with the same per-scene photometry and phase targets
    as the composite set's families, so it trains and evaluates beside it."""
    data = write_set(tmp_path, "composite_reliefs", counts=(1, 0, 0), workers=1)
    (sample,) = split_files(data, "train")
    assert sample_family(sample) == "reliefs"
    with np.load(sample) as z:
        assert z["code"].shape == (4, 480, 640) and z["fringe"].shape == (2, 480, 640)
        assert np.isfinite(z["label"]).mean() > 0.5
    assert yaml.safe_load((data / "dataset.yaml").read_text())["scene"] == "reliefs"


def test_the_main_surface_is_the_background_with_its_pieces_and_what_joins_it():
    """A plane tilted about 30 degrees (a plane in 3D: inverse depth linear in the rays), a block 30 mm
    tall (its top a plane too) across the whole height and more than half the width, cutting the plane
    in two, a plate 3 mm tall on one piece and a shadow: the main surface is both pieces of the plane
    with the plate (a step under the limit), not the block, though the largest surface, nor the pixels
    beside its edges, nor the shadow. With no background (a floating block's top and a larger curved
    object), the largest surface."""
    x, y = np.meshgrid((np.arange(100) - 50) / 500.0, (np.arange(80) - 40) / 500.0)
    plane = (1200.0 / (1.0 - 0.58 * x)).astype(np.float32)
    depth = plane.copy()
    depth[:, 20:76] = (1170.0 / (1.0 - 0.58 * x))[:, 20:76]  # the block: a plane too, with the background behind
    depth[50:60, 80:95] -= 3.0  # the plate
    depth[65:75, 5:15] = np.nan  # a shadow
    main = main_surface(depth, 4.7, (x, y))
    assert main[:, :19].any() and main[:, 77:].any() and main[50:60, 80:95].all()
    assert not main[:, 19:77].any() and not main[65:75, 5:15].any()
    assert main.sum() == 80 * (19 + 23) - 100
    floating = np.full_like(depth, np.nan)
    floating[10:40, 10:40] = (1180.0 / (1.0 - 0.58 * x))[10:40, 10:40]  # a plane, nothing behind it: 11% of the image
    floating[40:80, 50:100] = plane[40:80, 50:100] - 40.0 + 10.0 * x[40:80, 50:100] ** 2 * 100  # curved, larger
    main = main_surface(floating, 4.7, (x, y))
    assert main[50:70, 60:90].all() and not main[10:40, 10:40].any()


@pytest.mark.parametrize("arch, convs, pools, transposes", [("aen", 23, 5, 5), ("unet", 23, 5, 5), ("fcn", 16, 5, 3)])
def test_the_papers_networks(arch, convs, pools, transposes):
    model = build(arch, width=4, dropout=0.0, depth_mm=(1200.0, 50.0))
    # AEN / UNet: 22 convolutions + the final 1x1, 5 max-pools, 5 transpose convolutions = 33 layers
    assert layer_counts(model) == {"conv": convs, "maxpool": pools, "transpose": transposes}
    image, (h, w) = pad_to_stride(torch.rand(2, 1, 100, 150))
    assert image.shape[-2:] == (128, 160)
    assert model(image)[..., :h, :w].shape == (2, 1, 100, 150)


def test_training_writes_what_the_paper_shows(trained):
    out, _ = trained
    for name in ("last.pt", "best.pt", "losses.csv", "losses.png", "epochs/epoch_0001.png"):
        assert (out / name).is_file(), name
    ckpt = load_checkpoint(out / "last.pt")
    assert ckpt["epoch"] == 1 and ckpt["config"]["arch"] == "unet" and np.isfinite(ckpt["history"][0]["val_rmse_mm"])
    assert model_from_checkpoint(ckpt)[0].head.depth_offset == 1150.0  # the output's millimetres travel with it


def test_resume_goes_on_from_the_checkpoint(trained):
    out, cfg = trained
    cfg2 = TrainConfig(**{**cfg.__dict__, "epochs": 2})
    train(cfg2, resume=str(out / "last.pt"))
    ckpt = load_checkpoint(out / "last.pt")
    assert ckpt["epoch"] == 2 and [h["epoch"] for h in ckpt["history"]] == [1, 2]


def test_checkpoints_never_run_pickled_code(tmp_path):
    class Evil:
        def __reduce__(self):
            return (print, ("pwned",))

    path = tmp_path / "evil.pt"
    path.write_bytes(pickle.dumps({"format": "fpp_checkpoint", "x": Evil()}))
    with pytest.raises(ValueError, match="cannot load checkpoint"):
        load_checkpoint(path)


def test_torchrun_with_two_cpu_processes(tiny_set, tmp_path):
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "torch.distributed.run",
            "--nproc_per_node",
            "2",
            "-m",
            "training.train",
            "--data",
            str(tiny_set),
            "--out",
            str(tmp_path),
            "--arch",
            "aen",
            "--width",
            "4",
            "--epochs",
            "1",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.count("epoch 1:") == 1  # only rank 0 reports and saves
    assert load_checkpoint(tmp_path / "last.pt")["epoch"] == 1


def test_export_parity_card_and_onnxruntime(trained, tmp_path):
    out, _ = trained
    card = export(str(out / "last.pt"), str(tmp_path / "m.onnx"))
    assert card["parity"]["max_abs_diff_mm"] < 1e-3 and card["parity"]["size"] != [224, 320]
    model = DepthModel(tmp_path / "m.onnx", threads=1)
    fringes = np.broadcast_to(128 + 100 * np.sin(np.arange(640) * 2 * np.pi / 9), (480, 640)).astype(np.uint8)
    depth = model(fringes)
    assert depth.shape == (480, 640) and depth.dtype == np.float32 and np.isfinite(depth).all()
    assert np.isnan(model(np.zeros((480, 640), np.uint8))).all()  # no fringes: no depth
    with pytest.raises(ModelError, match="640x480"):
        model(np.zeros((240, 320), np.uint8))
    with pytest.raises(ModelError, match="mono8 or mono16"):
        model(np.zeros((480, 640), np.float32))
    with pytest.raises(ValueError, match="no phase-aware model"):  # a depth regressor has no rules to choose
        choose_again(str(tmp_path / "m.onnx"), ["data"])
    (tmp_path / "m.onnx").write_bytes((tmp_path / "m.onnx").read_bytes()[:1000])
    with pytest.raises(ModelError, match="does not match its card"):
        DepthModel(tmp_path / "m.onnx")
    (tmp_path / "m.yaml").unlink()
    with pytest.raises(ModelError, match="has no card"):
        DepthModel(tmp_path / "m.onnx")


def test_a_model_for_another_composite_is_refused(tmp_path):
    """A composite network that reads a different number of code gratings (the first composite's one)
    with a card otherwise like the shipped one: a clear error, not a decoder reading the wrong channels."""
    import hashlib

    from fpp_nodes.core.model import default_model_path

    path = tmp_path / "one_code.onnx"
    torch.onnx.export(
        Strided(CompositeNet(4, gratings=2).eval()),
        (torch.zeros(1, 1, 64, 64),),
        str(path),
        dynamo=False,
        input_names=["image"],
        output_names=["fringe_phases"],
        dynamic_axes={"image": {0: "batch", 2: "height", 3: "width"}},
        opset_version=17,
    )
    card = yaml.safe_load(Path(default_model_path()).with_suffix(".yaml").read_text())
    card.update(model=path.name, sha256=hashlib.sha256(path.read_bytes()).hexdigest())
    card["output"]["pixel_shuffle"] = 2
    path.with_suffix(".yaml").write_text(yaml.safe_dump(card))
    with pytest.raises(ModelError, match="4 channels: it was trained for another composite pattern"):
        DepthModel(path)


@pytest.mark.parametrize("r, shape", [(2, (24, 5, 7)), (3, (18, 4, 6)), (4, (96, 3, 5))])
def test_the_models_pixel_shuffle_is_torchs(r, shape):
    x = np.random.default_rng(r).random(shape, dtype=np.float32)
    expected = torch.nn.functional.pixel_shuffle(torch.from_numpy(x)[None], r)[0].numpy()
    np.testing.assert_array_equal(pixel_shuffle(x, r), expected)


@pytest.mark.parametrize(
    "args, message",
    [
        (["training.evaluate", "--data", "{tmp}", "--families", "x.onnx"], "holds no data set (no dataset.yaml)"),
        (["training.evaluate", "--data", "{tiny_set}", "--families", "{tmp}/x.onnx"], "does not exist"),
        (["training.export", "{tmp}/x.pt", "--out", "{tmp}/x.onnx"], "cannot load checkpoint"),
        (["training.export", "{tmp}/x.onnx", "--data", "{tiny_set}"], "is no exported model"),
    ],
)
def test_missing_data_checkpoints_and_models_are_one_error_line(tiny_set, tmp_path, args, message):
    command = [a.format(tmp=tmp_path, tiny_set=tiny_set) for a in args]
    r = subprocess.run([sys.executable, "-m", *command], capture_output=True, text=True, timeout=120)
    assert r.returncode == 1 and message in r.stderr and "Traceback" not in r.stderr, r.stderr[-2000:]


def test_evaluate_prints_table_1(trained, tiny_set):
    out, _ = trained
    r = subprocess.run(
        [sys.executable, "-m", "training.evaluate", "--data", str(tiny_set), str(out / "last.pt")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    rows = {line[:28].strip(): line[28:].split() for line in r.stdout.splitlines()}
    assert rows[""] == ["UNET", "FTP", "multi-shot"]
    assert float(rows["Test RMSE vs exact (mm)"][2]) < 0.06  # the multi-shot label against the exact depth
    assert all(np.isfinite(float(v)) for v in rows["Test RMSE (mm)"])


def test_cnn_depth_node(trained, tmp_path, ros_graph):
    """The node in its own process: a frame in, depth and cloud out; bad frames are errors it survives;
    a corrupt model stops it with one line."""
    from sensor_msgs.msg import Image, PointCloud2
    from std_msgs.msg import Header

    from fpp_msgs_py import Qos, Topics, image_to_numpy, numpy_to_image

    out, _ = trained
    export(str(out / "last.pt"), str(tmp_path / "m.onnx"))
    procs, robot = ros_graph
    from fpp_nodes.core.calibration import Calibration, default_calibration_path

    # the model reads the paper's frame (its data set's): a rig calibrated to show it
    Calibration.load(default_calibration_path()).with_papers_single_shot().save(tmp_path / "paper.yaml")
    procs.start(
        "cnn_depth",
        "-p",
        f"model:={tmp_path / 'm.onnx'}",
        "-p",
        "threads:=1",
        "-p",
        f"calibration:={tmp_path / 'paper.yaml'}",
    )
    depth, clouds = [], []
    robot.node.create_subscription(Image, Topics.DEPTH, depth.append, Qos.LARGE)
    robot.node.create_subscription(PointCloud2, Topics.POINTS, clouds.append, Qos.LARGE)
    pub = robot.node.create_publisher(Image, Topics.CAMERA_IMAGE, Qos.FRAMES)
    assert robot.spin_until(lambda: pub.get_subscription_count() > 0, 30)
    image, _, _ = load_sample(split_files(trained[1].data, "test")[0])
    for bad, said in (
        (np.zeros((240, 320), np.uint8), "the model takes 640x480 images"),
        (np.zeros((480, 640), np.float32), "mono8 or mono16"),
    ):
        # one at a time (the node keeps only the newest frame), again until it is heard: until the node
        # sees a subscriber to its depth it skips frames
        for _ in range(120):
            pub.publish(numpy_to_image(bad, Header(frame_id="camera_optical_frame")))
            if robot.spin_until(lambda: said in procs.logs(), 0.5):
                break
        assert said in procs.logs(), procs.logs()
    pub.publish(numpy_to_image(image, Header(frame_id="camera_optical_frame")))
    assert robot.spin_until(lambda: depth and clouds, 60), procs.logs()
    d = image_to_numpy(depth[0])
    assert d.shape == (480, 640) and 1.0 < np.nanmedian(d) < 1.4 and clouds[0].height == 480
    assert "image rejected: the model takes 640x480 images" in procs.logs()
    (tmp_path / "bad.onnx").write_bytes(b"not a model")
    bad = procs.start("cnn_depth", "-p", f"model:={tmp_path / 'bad.onnx'}")
    assert bad.wait(timeout=60) == 2
    assert "has no card" in procs.logs() and "Traceback" not in procs.logs()


def write_bag(path, calibration, images) -> None:
    """A bag as record writes one: the calibration, then projector and camera joining mid-sequence, then
    one whole sequence of these camera images."""
    from rclpy.serialization import serialize_message

    from fpp_msgs_py import header_at, numpy_to_image
    from fpp_nodes.bag import BagWriter
    from fpp_nodes.core.patterns import pattern_images

    patterns = calibration.patterns
    writer = BagWriter(path)
    writer.write_calibration(calibration.to_yaml(), 0)
    t = 1_000_000_000
    for k in list(range(5, patterns.count)) + list(range(patterns.count)):
        header = header_at(t, "camera_optical_frame")
        pattern = numpy_to_image(pattern_images(patterns)[k], header)
        writer.write("/projector/pattern", "sensor_msgs/msg/Image", t, serialize_message(pattern))
        frame = numpy_to_image(images[k], header)
        writer.write("/camera/image_raw", "sensor_msgs/msg/Image", t + 1000, serialize_message(frame))
        t += 33_000_000
    writer.close()


def test_a_data_set_from_a_recorded_bag(tmp_path, capsys, near_rig, near_calibration):
    """What a user with real hardware does: record full sequences, label them with the multi-shot path;
    here a rig at 600 mm, whose labels are kept at their own depths (float32 mm). The evaluation runs
    a model with the set's calibration and, with no exact depth, judges it against the label."""
    from fpp_nodes.core.scenes import make_scene
    from fpp_nodes.core.simulation import render
    from training.dataset import write_bag_set

    rig, patterns = near_rig, near_calibration.patterns
    capture = render(rig, make_scene(rig, "objects", 21), patterns, np.random.default_rng(21))
    write_bag(tmp_path / "bag", near_calibration, capture.images)
    assert write_bag_set(tmp_path / "bag", tmp_path / "set") == 1
    image, label, truth = load_sample(split_files(tmp_path / "set", "train")[0])
    np.testing.assert_array_equal(image, capture.images[patterns.single_shot_index])
    with np.load(split_files(tmp_path / "set", "train")[0]) as z:  # what the composite network learns
        assert z["code"].shape == (4, 480, 640) and z["fringe"].shape == (2, 480, 640)  # two code gratings
    ok = np.isfinite(label) & capture.valid
    assert not np.isfinite(truth).any() and ok.sum() > 0.9 * capture.valid.sum()
    assert np.sqrt(np.mean((label - capture.depth_mm)[ok] ** 2)) < 0.06
    assert write_bag_set(tmp_path / "bag", tmp_path / "set", split="test") == 1
    info = yaml.safe_load((tmp_path / "set" / "dataset.yaml").read_text())
    assert info["counts"] == {"train": 1, "test": 1} and info["bags"] == {
        "train": [str(tmp_path / "bag")],
        "test": [str(tmp_path / "bag")],
    }
    with pytest.raises(ValueError, match="another rig"):  # one set, one rig
        write_bag_set(tmp_path / "bag", tmp_path / "set", calibration_path=default_calibration_path())
    capsys.readouterr()
    family_table(str(tmp_path / "set"), [default_model_path()])
    lines = capsys.readouterr().out.splitlines()
    row = next(line for line in lines if line.startswith("bag "))  # by recording
    rmse, off, orders, cover = (float(cell.rstrip("%")) for cell in row.split()[1:5])  # the shipped network's cells
    assert rmse < 0.2 and off < 0.5 and orders < 0.05 and cover > 90.0, row
    pooled = next(line for line in lines if line.startswith(f"{ALL_FAMILIES} "))  # one recording: the same cells
    assert pooled.split()[1:] == row.split()[1:], (pooled, row)
    refusal_table(str(tmp_path / "set"), default_model_path())  # where the rest of the lit pixels went
    shares = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("bag lit"))
    shares = [float(cell.rstrip("%")) for cell in shares.split()[2:]]
    assert len(shares) == len(REFUSAL_STEPS) + 1 and abs(sum(shares) - 100) < 0.05 and abs(shares[-1] - cover) < 0.06


def test_the_phase_aware_network_trains_exports_and_runs(tmp_path):
    """A families set with phase targets, one epoch of the phase-aware network, export with a threshold
    chosen on the validation split, onnxruntime inference with a confidence, and the per-family table."""
    data = write_set(tmp_path / "data", "families", counts=(2, 1, 2), workers=1)
    fringe, phase, family = load_phase_targets(split_files(data, "train")[0])
    assert fringe.shape == (2, 480, 640) and np.isfinite(phase).mean() > 0.3 and family == "bust"
    train(TrainConfig(data=str(data), out=str(tmp_path / "run"), arch="phase", width=4, downsample=1, epochs=1))
    # depth-regressing heads start at the set's rig: its calibration's reference depth unless given
    assert load_checkpoint(tmp_path / "run" / "last.pt")["config"]["depth_offset_mm"] == 1200.0
    card = export(str(tmp_path / "run" / "last.pt"), str(tmp_path / "m.onnx"))
    assert card["output"]["name"] == "fringe_order" and "val" in card["decoding"]["chosen_on"]
    assert card["calibration"]["camera"]["width"] == 640
    depth, confidence = DepthModel(tmp_path / "m.onnx", threads=1).infer(load_sample(split_files(data, "test")[0])[0])
    known = np.isfinite(confidence)  # NaN where the image shows no usable fringes
    assert depth.shape == confidence.shape == (480, 640) and known.mean() > 0.3
    assert np.all((confidence[known] >= 0) & (confidence[known] <= 1))
    assert np.all(np.isnan(depth[confidence < card["decoding"]["min_confidence"]]))
    r = subprocess.run(
        [sys.executable, "-m", "training.evaluate", "--data", str(data), "--families", str(tmp_path / "m.onnx")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0 and "bust" in r.stdout and "freeform" in r.stdout, r.stderr[-2000:]
    with pytest.raises(ValueError, match="downsample 1"):
        TrainConfig(arch="phase", downsample=2)
    with pytest.raises(ValueError, match="defocus_px blurs the composite"):
        TrainConfig(arch="phase", downsample=1, defocus_px=1.0)


def test_the_composite_loss_weighs_pixels_to_refuse_as_the_refused_amplitude():
    """Each trusted pixel's squared error over its carrier amplitude squared; a pixel whose targets are all
    zero (to show no fringes) over REFUSED_AMPLITUDE squared, not over the floor's (which would weigh it
    225 times more); an untrusted one (NaN) not at all."""
    targets = torch.zeros(1, 2 + 2 * len(COMPOSITE_CODES), 1, 3)
    targets[0, :2, 0, 0] = torch.tensor([0.3, 0.4])  # amplitude 0.5
    targets[0, 2:, 0, 2] = float("nan")
    pred = targets.nan_to_num() + torch.tensor([0.03] + [0.0] * (len(targets[0]) - 1))[None, :, None, None]
    expected = 10.0 * (0.03**2 / 0.5**2 + 0.03**2 / REFUSED_AMPLITUDE**2) / 2
    assert composite_loss(pred, targets).item() == pytest.approx(expected, rel=1e-5)


def test_composite_bars_show_no_fringes_on_part_of_their_trusted_pixels(tmp_path):
    """composite_bars' training scenes: every target zero (the network is taught to show no fringes) on the
    barred patches' trusted pixels, which are part, not all, of the scene's."""
    data = write_set(tmp_path / "data", "composite_bars", counts=(1, 0, 0), workers=1)
    with np.load(split_files(data, "train")[0]) as z:
        targets = np.concatenate([z["fringe"], z["code"]]).astype(np.float32)
    trusted = np.isfinite(targets).all(axis=0)
    refused = (targets[:, trusted] == 0).all(axis=0).mean()
    assert 0.05 < refused < 0.95, refused


@pytest.mark.parametrize("rank", [1, 2])
def test_separable_layers_start_from_a_full_networks_weights(tmp_path, rank):
    """A full composite network's last two middle layers load into Separable ones of rank products per
    input channel (make separable-model): exactly where each input channel's kernels span rank kernels
    (the same outputs), and otherwise as the sum nearest them (no better fit of that rank exists)."""
    torch.manual_seed(0)
    full = CompositeNet(8)
    for layer in (full.net[6], full.net[8]):  # each input channel's kernels: rank kernels mixed
        layer.weight.data = torch.einsum("oir,rixy->oixy", torch.randn(8, 8, rank), torch.randn(rank, 8, 3, 3))
    torch.save({"format": "fpp_checkpoint", "model": full.state_dict()}, tmp_path / "full.pt")
    separable = CompositeNet(8, separable=2, separable_rank=rank)
    assert [isinstance(separable.net[i], Separable) for i in (2, 4, 6, 8)] == [False, False, True, True]
    with pytest.raises(ValueError, match="separable must be 0-4"):
        CompositeNet(8, separable=5)
    load_initial_weights(separable, tmp_path / "full.pt", f"composite, width 8, separable 2 of rank {rank}")
    image = torch.rand(1, 1, 64, 96)
    with torch.no_grad():
        assert torch.allclose(separable(image), full(image), atol=1e-5)
    weight = torch.randn(8, 8, 3, 3)
    factors = Separable.factored(weight, torch.zeros(8), rank)
    product = sum(
        factors[f"terms.{k}.1.weight"] * factors[f"terms.{k}.0.weight"].transpose(0, 1) for k in range(rank)
    )  # (out, in, 3, 3)
    for i in range(8):
        kernels = weight[:, i].reshape(8, 9)
        missed = torch.linalg.norm(kernels - product[:, i].reshape(8, 9)) ** 2
        assert torch.isclose(missed, (torch.linalg.svdvals(kernels)[rank:] ** 2).sum(), rtol=1e-4)


def test_the_composite_network_trains_exports_and_runs(tmp_path):
    """A composite set (the composite frame, carrier and code targets), one epoch on crops, export with
    a threshold chosen on the validation split, and onnxruntime inference with the physics decoder."""
    data = write_set(tmp_path / "data", "composite", counts=(2, 1, 1), workers=1)
    with np.load(split_files(data, "train")[0]) as z:
        assert z["code"].shape == (4, 480, 640) and str(z["family"]) == "bust"  # two code gratings
    config = TrainConfig(
        data=str(data),
        out=str(tmp_path / "run"),
        arch="composite",
        width=4,
        downsample=1,
        epochs=1,
        crop=160,
        batch_size=4,
    )
    train(config)
    # a second stage starts from the first's weights (at a rate too small to move them here), with the
    # training scenes of a set striped near the carrier added (make stripes-model); another rig's refused
    first = load_checkpoint(tmp_path / "run" / "last.pt")["model"]
    stripes = write_set(tmp_path / "data", "composite_stripes", counts=(1, 0, 0), workers=1)
    more = replace(  # and half its crops defocused (make separable-model's last stage)
        config, out=str(tmp_path / "more"), lr=1e-12, init=str(tmp_path / "run" / "last.pt"), defocus_px=2.5
    )
    train(replace(more, extra=str(stripes)))
    second = load_checkpoint(tmp_path / "more" / "last.pt")
    assert all(torch.allclose(first[k], second["model"][k], atol=1e-6) for k in first)
    assert second["counts"] == {"train": 3, "val": 1}
    info = yaml.safe_load((stripes / "dataset.yaml").read_text())
    info["calibration"]["camera"]["fx"] += 1.0
    (stripes / "dataset.yaml").write_text(yaml.safe_dump(info))
    with pytest.raises(ValueError, match="are not all of one rig"):
        train(replace(more, extra=str(stripes)))
    write_set(tmp_path / "data", "composite", counts=(3, 1, 1), workers=1)  # the set grows after training
    card = export(str(tmp_path / "run" / "last.pt"), str(tmp_path / "m.onnx"))
    assert card["training"]["counts"] == {"train": 2, "val": 1, "test": 1}  # what it learned from
    assert card["output"]["name"] == "fringe_phases" and card["input"]["content"] == "single-shot composite"
    assert card["output"]["pixel_shuffle"] == 2  # the ONNX file ends before it (parity checked through it)
    assert card["calibration"]["working_range_mm"] == [1000.0, 1350.0] and "val" in card["decoding"]["chosen_on"]
    # a rig's recordings fine-tune from an exported model, the shipped one's way (no checkpoint shipped)
    train(replace(config, out=str(tmp_path / "tuned"), lr=1e-12, init=str(tmp_path / "m.onnx")))
    tuned = load_checkpoint(tmp_path / "tuned" / "last.pt")["model"]
    assert all(torch.allclose(first[k], tuned[k], atol=1e-6) for k in first)
    with pytest.raises(ValueError, match="another network than this run's \\(composite, width 8\\)"):
        train(replace(config, out=str(tmp_path / "wider"), width=8, init=str(tmp_path / "m.onnx")))
    model = DepthModel(tmp_path / "m.onnx", threads=1)
    assert model.reads == "composite"
    # a candidate judged by another card's rules: those rules, unchosen
    kept = export(str(tmp_path / "run" / "last.pt"), str(tmp_path / "kept.onnx"), rules_of=str(tmp_path / "m.onnx"))
    assert kept["decoding"] == {k: card["decoding"][k] for k in RULES} | {
        "chosen_on": f"the rules of {tmp_path / 'm.onnx'}'s card"
    }
    with pytest.raises(ValueError, match="has no card beside it"):
        export(str(tmp_path / "run" / "last.pt"), str(tmp_path / "x.onnx"), rules_of=str(tmp_path / "none.onnx"))
    # the four rules chosen together on validation, and the ones the model runs with
    assert model.min_modulation == card["decoding"]["min_modulation"] in FLOOR_GRID
    assert model.decoder.min_surface_px == card["decoding"]["min_surface_px"] in SURFACE_GRID
    assert model.max_roughness_mm == card["decoding"]["max_roughness_mm"] in ROUGHNESS_GRID
    assert model.margin_px == card["decoding"]["margin_px"] in MARGIN_GRID
    # then the stripes rule, the lowest threshold whose false alarms on validation stay within budget
    sidebands = card["decoding"]["sidebands"]
    assert model.decoder.max_sideband == card["decoding"]["max_sideband"] in (*SIDEBAND_GRID, np.inf)
    assert all((sidebands[str(t)] <= SIDEBAND_REFUSAL_BUDGET) == (t >= model.max_sideband) for t in SIDEBAND_GRID)
    # and the rule against surfaces outside the working range, within its budget
    outside = card["decoding"]["outside"]
    assert model.decoder.max_outside == card["decoding"]["max_outside"] in (*OUTSIDE_GRID, np.inf)
    assert all((outside[str(t)] <= OUTSIDE_REFUSAL_BUDGET) == (t >= model.max_outside) for t in OUTSIDE_GRID)
    rule = rule_name(model.min_modulation, model.decoder.min_surface_px, model.max_roughness_mm, model.margin_px)
    chosen = card["decoding"]["validation"][rule][str(model.min_confidence)]
    within = chosen["silent_errors"] <= SILENT_ERROR_BUDGET and chosen["wrong_orders"] <= WRONG_ORDER_BUDGET
    assert (within and chosen["worst_family_silent_errors"] <= SILENT_ERROR_LIMIT) or (
        model.min_confidence == CONFIDENCE_GRID[-1]
    )
    depth, confidence = model.infer(load_sample(split_files(data, "test")[0])[0])
    sure = confidence[np.isfinite(confidence)]
    assert sure.size and sure.min() >= 0 and sure.max() <= 1
    assert np.all(np.isnan(depth[~(confidence >= model.min_confidence)]))
    # trained elsewhere (a GPU machine's set is gone): the rules and calibration come from a set here
    moved = data.rename(tmp_path / "here")
    card = export(str(tmp_path / "run" / "last.pt"), str(tmp_path / "m2.onnx"), data=[str(moved)])
    assert card["decoding"]["chosen_on"].startswith(str(moved)) and card["training"]["data"] == str(data)
    assert card["calibration"]["camera"]["width"] == 640
    # the exported model's rules chosen again from its ONNX file (a card without them): the same rules and file
    stale = yaml.safe_load((tmp_path / "m2.yaml").read_text()) | {"decoding": {}}
    (tmp_path / "m2.yaml").write_text(yaml.safe_dump(stale, sort_keys=False))
    again = choose_again(str(tmp_path / "m2.onnx"), [str(moved)])
    assert again["decoding"] == card["decoding"] and again["sha256"] == card["sha256"] == sha256(tmp_path / "m2.onnx")
    assert DepthModel(tmp_path / "m2.onnx").min_confidence == card["decoding"]["min_confidence"]
    # and on hard validation scenes beside them (one of each condition), of the same rig only
    hard = write_set(tmp_path / "data", "composite_hard", counts=(0, 2, 0), workers=1)
    conditions = [sample_family(f) for f in split_files(hard, "val")]
    assert sorted(conditions) == sorted(HARD_CONDITIONS)
    both = choose_again(str(tmp_path / "m2.onnx"), [str(moved), str(hard)])["decoding"]
    assert both["chosen_on"] == f"{moved} val and {hard} val, 3 samples"
    other_rig = yaml.safe_load((hard / "dataset.yaml").read_text())
    other_rig["calibration"]["camera"]["fx"] += 1.0
    (hard / "dataset.yaml").write_text(yaml.safe_dump(other_rig))
    with pytest.raises(ValueError, match="not all of one rig"):
        choose_again(str(tmp_path / "m2.onnx"), [str(moved), str(hard)])
    (tmp_path / "m2.yaml").write_text((tmp_path / "m2.yaml").read_text().replace(card["sha256"], "0" * 64))
    with pytest.raises(ValueError, match="does not match its card"):
        choose_again(str(tmp_path / "m2.onnx"), [str(moved)])


def test_a_turned_rigs_recordings_train_as_the_shipped_network_reads_frames(tmp_path, rig, patterns):
    """A rig whose frames the network is shown turned (a projector above the camera, a camera mounted
    turned, a projector in rear mode: model.network_layout) labels its own recordings, in its own
    layout; training and export's choice of rules show the network those frames laid out as the
    simulated rig's, as cnn_depth does, so a fine-tune starts from weights that read them. Emulated
    exactly: a set's samples and the calibration's planes turned a quarter (a portrait camera). Fine-tuned
    from the shipped network at a rate too small to move it, it validates and measures as the shipped
    network on the same frames. Before, it was shown them as they are: 6 epochs on 48 such samples gave
    the held-out spheres 68.8% at 1.05% off by more than 1 mm, against the same fine-tune upright and
    after this, 90.4-90.6% at 0.15% (the throwaway runs/s86/turned_finetune.py)."""
    from fpp_nodes.core.scenes import SURFACE_DEPTH_MM, plane_scene
    from fpp_nodes.core.workflow import CALIBRATION_DEPTHS_MM, calibrate_from_planes

    def turned(a):
        return np.ascontiguousarray(np.rot90(a, 1, axes=(-2, -1)))

    rng = np.random.default_rng(7)
    planes = [turned(render(rig, plane_scene(rig, z), patterns, rng).images) for z in CALIBRATION_DEPTHS_MM]
    portrait = Rig(width=rig.height, height=rig.width).camera()
    calibration, _ = calibrate_from_planes(
        planes, list(CALIBRATION_DEPTHS_MM), portrait, patterns, working_range_mm=SURFACE_DEPTH_MM
    )
    upright = write_set(tmp_path / "data", "composite", counts=(1, 1, 1), workers=1)
    info = yaml.safe_load((upright / "dataset.yaml").read_text()) | {"calibration": calibration.to_dict()}
    data = tmp_path / "turned"
    for f in split_files(upright, "train") + split_files(upright, "val") + split_files(upright, "test"):
        (data / f.parent.name).mkdir(parents=True, exist_ok=True)
        with np.load(f) as z:
            arrays = {k: turned(v) if v.ndim > 1 else v for k, v in z.items()}
        np.savez_compressed(data / f.parent.name / f.name, **arrays)
    (data / "dataset.yaml").write_text(yaml.safe_dump(info, sort_keys=False))
    config = TrainConfig(
        arch="composite", width=16, downsample=1, epochs=1, crop=160, batch_size=4, lr=1e-12, init=default_model_path()
    )
    validated = [
        train(replace(config, data=str(d), out=str(tmp_path / "runs" / d.name)))["val_coverage"]
        for d in (upright, data)
    ]
    assert validated[0] > 0.9 and validated[1] == pytest.approx(validated[0], abs=0.005)
    checkpoint = str(tmp_path / "runs" / "turned" / "last.pt")
    chosen = export(checkpoint, str(tmp_path / "chosen.onnx"))["decoding"]  # rules chosen on the frames laid out
    rule = rule_name(
        chosen["min_modulation"], chosen["min_surface_px"], chosen["max_roughness_mm"], chosen["margin_px"]
    )
    assert chosen["validation"][rule][str(chosen["min_confidence"])]["coverage"] > 0.9
    card = export(checkpoint, str(tmp_path / "m.onnx"), rules_of=default_model_path())
    assert card["input"]["layout"] == TRAINING_LAYOUT
    tuned, shipped = DepthModel(tmp_path / "m.onnx", threads=1), DepthModel(default_model_path(), threads=1)
    shipped.use(calibration)
    assert tuned.layout == shipped.layout == Layout(True, (1,))
    image = load_sample(split_files(data, "test")[0])[0]
    ours, theirs = tuned(image), shipped(image)
    assert np.isfinite(theirs).mean() > 0.5
    assert np.mean(np.isfinite(ours) != np.isfinite(theirs)) < 0.01
    both = np.isfinite(ours) & np.isfinite(theirs)
    assert np.mean(np.abs(ours - theirs)[both] > 0.01) < 0.001  # the same network and layout: the same depth
    # a network trained on such a rig's frames as they are (exported before the layout was on its card) is refused
    before = card | {"input": card["input"] | {"layout": None}}
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(before, sort_keys=False))
    with pytest.raises(ModelError, match="trained on its rig's frames as they are"):
        DepthModel(tmp_path / "m.onnx")


def test_training_shows_a_network_a_frame_as_cnn_depth_does():
    """LaidOut (training, export's rules) and DepthModel (cnn_depth, fpp) turn a frame the same way, a
    tilted one too (a camera or projector rolled): into the same canvas, and the outputs back."""
    import cv2

    layout = Layout(True, (1,), -12.0)
    image = cv2.GaussianBlur(np.random.default_rng(0).random((480, 640)).astype(np.float32), (0, 0), 3)
    seen = []

    class Spy(torch.nn.Module):
        def forward(self, x):
            seen.append(x)
            return x

    out = LaidOut(Spy(), layout)(torch.from_numpy(image)[None, None])[0].numpy()
    shown = layout.shown(image)
    assert shown.shape[::-1] == layout.size((640, 480)) == (603, 726)
    np.testing.assert_allclose(seen[0][0, 0, :726, :603].numpy(), shown, atol=1e-5)
    np.testing.assert_allclose(out, layout.undone(shown[None], (640, 480)), atol=1e-5)


def test_the_exact_depths_phases_decode_to_it(rig, calibration):
    """evaluate --refusals --exact: the phases exact_outputs puts in a network's outputs, from a scene's
    exact depth through the calibration, decode back to that depth (within the calibration's 0.05 mm) at
    every lit pixel but a step's, at the network's own amplitudes; where the depth is unknown the network's
    outputs stay."""
    scene = make_scene(rig, "blocks", 5)
    rng = np.random.default_rng(0)
    out = rng.uniform(-0.3, 0.3, (2 + 2 * len(COMPOSITE_CODES), *scene.depth_mm.shape)).astype(np.float32)
    exact = exact_outputs(out, scene.depth_mm, calibration)
    known = np.isfinite(scene.depth_mm)
    assert np.allclose(np.hypot(exact[0::2], exact[1::2]), np.hypot(out[0::2], out[1::2]), rtol=1e-4)
    assert np.array_equal(exact[:, ~known], out[:, ~known])
    depth, _ = CompositeDecoder(calibration)(exact, 0.5, known)
    given = np.isfinite(depth)
    assert given.sum() > 0.97 * known.sum() and np.abs(depth - scene.depth_mm)[given].max() < 0.05


def test_defocusing_a_sample_is_what_a_more_defocused_camera_gives():
    """train --defocus-px: a composite sample blurred by one more Gaussian of 1.5 px is the sample the rig
    gives with that much more blur (sqrt(0.6^2 + 1.5^2) px, noise off): the image within the 8-bit
    rounding, the carrier's phase within 0.03 rad at the median (its noise in these images is about that),
    its amplitude within 3%, the codes' phases kept; what the sample did not trust, it still does not."""
    calibration = Calibration.load(default_calibration_path())
    patterns, psp = calibration.patterns, PspReconstructor(calibration)
    samples = []
    for blur in (0.6, float(np.hypot(0.6, 1.5))):
        rig = replace(Rig(), blur_sigma_px=blur, noise_sigma=0.0)
        capture = render(rig, make_scene(rig, "freeform", 3), patterns)
        targets = phase_targets(capture.images, psp(capture.images), calibration)
        image = network_input(capture.images[patterns.single_shot_index])
        samples.append((image, np.concatenate([targets["fringe"], targets["code"]]).astype(np.float32)))
    (image, targets), (want_image, want) = samples
    got_image, got = defocused(image, targets, 1.5)
    inner = (slice(8, -8), slice(8, -8))
    assert np.abs(got_image - want_image)[inner].max() < 1.5 / 255
    both = np.isfinite(got).all(axis=0) & np.isfinite(want).all(axis=0)
    assert both.mean() > 0.9

    def phases(t):  # the carrier's, then each code's
        return np.arctan2(t[0::2], t[1::2])

    assert np.median(np.abs(wrap_phase(phases(got)[0] - phases(want)[0])[both])) < 0.03
    amplitude, want_amplitude = np.hypot(got[0], got[1])[both], np.hypot(want[0], want[1])[both]
    assert np.median(np.abs(amplitude / want_amplitude - 1)) < 0.03
    assert np.abs(wrap_phase(phases(got)[1:] - phases(targets)[1:])[:, both]).max() < 1e-4
    assert not np.isfinite(got[:, ~np.isfinite(targets).all(axis=0)]).any()


def test_the_code_comparison_measures_margins_as_the_decoder_does():
    """training.compare_codes' margin for the shipped design (half the closest two orders' codes over the
    working range) agrees with the shipped decoder's own; the first composite's one code had less than
    a fifth of it; the network reads the shipped pattern's three gratings (six channels)."""
    rig = Rig()
    decoder = CompositeDecoder(Calibration.load(default_calibration_path()))
    shipped = margin(DESIGNS["two codes, rows 12/24"], rig)
    assert shipped == pytest.approx(decoder.min_separation / 2, rel=0.1)
    assert margin(DESIGNS["one code (the first)"], rig) < shipped / 5
    # a third code, rows 96 px apart: it alone keeps an order in range from those outside by the range's
    # own margin (scripts/code_aliasing.py's geometry)
    assert third_margin(DESIGNS["+ (180, 96), 0.31/0.23"], rig) >= shipped
    for stride in (2, 4):  # either stride's pixel shuffle gives the full resolution back
        assert CompositeNet(4, stride=stride)(torch.zeros(1, 1, 32, 32)).shape == (1, 6, 32, 32)


def test_a_data_set_from_a_bag_of_a_12_bit_camera_in_mono16(tmp_path, calibration):
    """Its frames are learnt at full scale, as the nodes read them: the same input and targets as the
    rig's 16-bit frames would give, within the 12-bit quantization."""
    from dataclasses import replace

    from fpp_nodes.core.scenes import make_scene
    from fpp_nodes.core.simulation import Rig, render
    from training.dataset import read_info, write_bag_set

    rig = Rig(camera_bit_depth=16, noise_sigma=16.0)
    capture = render(rig, make_scene(rig, "objects", 21), calibration.patterns, np.random.default_rng(21))
    twelve = replace(calibration, camera=replace(calibration.camera, bits=12))
    for name, cal, images in (("wide", calibration, capture.images), ("twelve", twelve, capture.images >> 4)):
        write_bag(tmp_path / f"{name}.bag", cal, images.astype(np.uint16))
        assert write_bag_set(tmp_path / f"{name}.bag", tmp_path / name) == 1
    # the frames are stored widened, so the set's calibration is the 16-bit rig's: evaluate widens nothing again
    assert read_info(tmp_path / "twelve")["calibration"] == read_info(tmp_path / "wide")["calibration"]
    (wide,), (narrow,) = (split_files(tmp_path / name, "train") for name in ("wide", "twelve"))
    with np.load(wide) as w, np.load(narrow) as n:
        assert np.abs(n["input"].astype(int) - w["input"]).max() <= 16  # one 12-bit step
        both = np.isfinite(w["phase"]) & np.isfinite(n["phase"])
        assert both.sum() > 0.9 * np.isfinite(w["phase"]).sum()
        assert np.abs(n["fringe"][:, both].astype(np.float32) - w["fringe"][:, both]).max() < 0.01  # of full scale
