"""ONNX export with a parity check, and the model card beside the model.

    python -m training.export runs/unet/best.pt --out fpp_nodes/fpp_nodes/data/models/unet.onnx

The ONNX model has one input, `image` (float32, N x 1 x H x W, the camera image / full scale, at 1/
downsample of the camera's resolution, H and W multiples of 32) and one output, `depth_mm`
(float32, N x 1 x H x W, millimetres along the optical axis); height and width are dynamic. The export
is checked with onnx.checker, then run with onnxruntime at a size other than the training size and
compared with torch (PARITY_TOLERANCE_MM). The card (<model>.yaml) records the rig, input
normalisation, output units, training data and metrics, and the file's sha256.
"""
from __future__ import annotations

import argparse
import hashlib
import warnings
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import torch
import yaml

from .train import load_checkpoint, model_from_checkpoint

PARITY_TOLERANCE_MM = 1e-3
CARD_FORMAT = "fpp_model_card"


def sha256(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def export(checkpoint: str, out: str, parity_size=(192, 256), metrics: dict | None = None) -> dict:
    ckpt = load_checkpoint(checkpoint)
    model, cfg = model_from_checkpoint(ckpt)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    example = torch.rand(1, 1, 480 // cfg.downsample // 32 * 32, 640 // cfg.downsample // 32 * 32)
    warnings.filterwarnings("ignore", "You are using the legacy TorchScript-based ONNX export", DeprecationWarning)
    # dynamo=False: the TorchScript exporter gives plain dynamic height/width for this fully convolutional net
    torch.onnx.export(model, (example,), str(out), dynamo=False, input_names=["image"], output_names=["depth_mm"],
                      dynamic_axes={"image": {0: "batch", 2: "height", 3: "width"},
                                    "depth_mm": {0: "batch", 2: "height", 3: "width"}}, opset_version=17)
    onnx.checker.check_model(onnx.load(str(out)))
    probe = torch.rand(1, 1, *parity_size)
    with torch.no_grad():
        expected = model(probe).numpy()
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    got = session.run(["depth_mm"], {"image": probe.numpy()})[0]
    np.testing.assert_allclose(got, expected, atol=PARITY_TOLERANCE_MM, rtol=0)
    dataset = yaml.safe_load((Path(cfg.data) / "dataset.yaml").read_text()) if (Path(cfg.data) / "dataset.yaml").exists() else {}
    last = ckpt["history"][-1] if ckpt["history"] else {}
    card = {
        "format": CARD_FORMAT, "version": 1, "model": out.name, "sha256": sha256(out),
        "architecture": cfg.arch, "width": cfg.width, "parameters": sum(p.numel() for p in model.parameters()),
        "input": {"name": "image", "shape": "N x 1 x H x W, H and W multiples of 32",
                  "normalisation": "camera image / full scale (255 for mono8, 65535 for mono16)",
                  "content": "the first phase-shifted image of the highest fringe frequency",
                  "downsample": cfg.downsample, "camera": dataset.get("calibration", {}).get("camera")},
        "output": {"name": "depth_mm", "units": "mm along the camera's optical axis"},
        "rig": dataset.get("rig"), "patterns": dataset.get("calibration", {}).get("patterns"),
        "training": {"data": cfg.data, "counts": dataset.get("counts"), "epochs": ckpt["epoch"],
                     "seconds": round(ckpt["train_seconds"], 1), "config": ckpt["config"]},
        "metrics": metrics or {"val_rmse_mm_vs_label": last.get("val_rmse_mm"), "val_mre_vs_label": last.get("val_mre")},
        "parity": {"size": list(parity_size), "max_abs_diff_mm": float(np.abs(got - expected).max()),
                   "tolerance_mm": PARITY_TOLERANCE_MM},
    }
    out.with_suffix(".yaml").write_text(yaml.safe_dump(card, sort_keys=False))
    return card


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m training.export", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("checkpoint")
    parser.add_argument("--out", required=True)
    args = parser.parse_args(argv)
    card = export(args.checkpoint, args.out)
    print(f"wrote {args.out} ({card['parameters']} parameters, sha256 {card['sha256'][:12]}...) and its card; "
          f"parity at {card['parity']['size']}: {card['parity']['max_abs_diff_mm']:.2e} mm")


if __name__ == "__main__":
    main()
