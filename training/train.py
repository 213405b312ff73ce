"""Training after the paper: mini-batches of 2, MSE loss on the valid label pixels (or binary cross-
entropy on labels normalised to [0, 1]), learning rate halved when the validation loss has not improved
for `patience` epochs, augmentation, weight decay, dropout. Every epoch: a checkpoint that describes
itself (config, weights, optimizer, metrics; loaded with weights_only=True, so no pickle runs), the
prediction of one fixed validation image as a picture (the paper's Visualization 2), the loss curves as CSV
and PNG. Resume with --resume. Several processes or machines: launch with torchrun
(DistributedDataParallel, gloo on the CPU, nccl on GPUs).

    python -m training.train --data data/fpp/single --arch unet --width 16 --epochs 300 --out runs/unet
    torchrun --nproc_per_node 2 -m training.train ...
"""

from __future__ import annotations

import argparse
import csv
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import cv2
import numpy as np
import onnx
import torch
import torch.distributed as dist
from onnx import numpy_helper
from torch.nn.parallel import DistributedDataParallel
from torch.utils.data import DataLoader, Dataset, DistributedSampler
from tqdm import tqdm

from fpp_nodes.core.metrics import ErrorTotals
from fpp_nodes.core.model import Layout, PhaseOrderDecoder, network_input, network_layout
from fpp_nodes.core.patterns import COMPOSITE_CODES
from fpp_nodes.core.reconstruct import CompositeDecoder
from fpp_nodes.pictures import depth_colours

from .dataset import load_phase_targets, load_sample, sets_calibration, split_files
from .models import ARCHITECTURES, LaidOut, Separable, build, pad_to_stride

BCE_RANGE_MM = (1100.0, 1300.0)  # labels map to [0, 1] over this depth range for the BCE loss


@dataclass
class TrainConfig:
    data: str = "data/fpp/single"
    extra: str = ""  # another set of the same rig whose training samples join data's (e.g. composite_stripes)
    out: str = "runs/unet"
    arch: str = "unet"
    width: int = 16
    downsample: int = 2  # train and infer at 1/downsample of the camera's resolution
    epochs: int = 300
    batch_size: int = 2
    lr: float = 1e-3
    weight_decay: float = 1e-4
    dropout: float = 0.1
    depth_offset_mm: float = (
        0.0  # depth-regressing networks: o -> offset + scale * o, mm (0: the rig's reference depth)
    )
    depth_scale_mm: float = 50.0
    patience: int = 20
    loss: str = "mse"
    augment: bool = True
    limit: int = 0  # use only the first N training samples (0: all)
    crop: int = 0  # train on random square crops of this size (0: whole images); composite only
    stride: int = 2  # the composite network's first layer's (2, or 4: a quarter of the pixels to convolve)
    separable: int = 0  # the composite network's last middle layers made Separable (from --init: factored)
    separable_rank: int = 1  # the separable convolutions each Separable layer sums
    defocus_px: float = 0.0  # composite: half the training crops blurred by one more Gaussian of sigma up to this
    workers: int = 0  # data-loading processes (worth it beside a GPU)
    init: str = ""  # start from these weights: a checkpoint, or a model file such as the shipped one
    seed: int = 0

    def __post_init__(self):
        if self.arch not in ARCHITECTURES:
            raise ValueError(f"arch must be one of {ARCHITECTURES}, got {self.arch!r}")
        if self.loss not in ("mse", "bce"):
            raise ValueError(f"loss must be mse or bce, got {self.loss!r}")
        if self.defocus_px < 0:
            raise ValueError(f"defocus_px must be >= 0, got {self.defocus_px}")
        if self.defocus_px and self.arch != "composite":
            raise ValueError(f"defocus_px blurs the composite network's targets: arch {self.arch} has none")
        if self.workers < 0:
            raise ValueError(f"workers must be >= 0, got {self.workers}")
        for name in ("width", "downsample", "epochs", "batch_size", "patience", "separable_rank"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.arch in ("phase", "composite") and self.downsample != 1:
            raise ValueError(f"the phase-aware networks (arch {self.arch}) need the full resolution: --downsample 1")
        if self.crop % 32:
            raise ValueError(f"crop must be a multiple of 32, got {self.crop}")

    def network(self) -> torch.nn.Module:
        """The untrained network this config describes."""
        depth_mm = (self.depth_offset_mm, self.depth_scale_mm)
        return build(self.arch, self.width, self.dropout, depth_mm, self.stride, self.separable, self.separable_rank)


def shrink(image: np.ndarray, factor: int, depth: bool = False) -> np.ndarray:
    """Downsample: area average for the fringe image, nearest for depth (never mixes two surfaces)."""
    if factor == 1:
        return image
    size = (image.shape[1] // factor, image.shape[0] // factor)
    return cv2.resize(image, size, interpolation=cv2.INTER_NEAREST if depth else cv2.INTER_AREA)


class FringeDepthSet(Dataset):
    """(image [0, 1], label mm, truth mm) tensors at 1/downsample resolution, all held in memory."""

    def __init__(self, files, downsample: int, augment: bool = False, seed: int = 0):
        self.items = []
        for f in files:
            image, label, truth = load_sample(f)
            self.items.append(
                (
                    shrink(network_input(image), downsample),  # as cnn_depth: scale, then shrink
                    shrink(label, downsample, True),
                    shrink(truth, downsample, True),
                )
            )
        self.augment = augment
        self.rng = np.random.default_rng(seed)

    def __len__(self):
        return len(self.items)

    def __getitem__(self, i):
        image, label, truth = self.items[i]
        if self.augment:
            image, _ = photometric(self.rng, image)
        return torch.from_numpy(image)[None], torch.from_numpy(label)[None], torch.from_numpy(truth)[None]


def photometric(rng, image: np.ndarray) -> tuple[np.ndarray, np.float32]:
    """Augmentation that moves no pixel off the calibration: gain, offset and noise on the image [0, 1].
    Returns it and the gain, which fringe amplitudes (numerators and denominators) follow."""
    gain = rng.uniform(0.8, 1.2)
    image = image * gain + rng.uniform(-0.04, 0.04)
    image = image + rng.normal(0, rng.uniform(0, 0.008), image.shape)
    return np.clip(image, 0, 1).astype(np.float32), np.float32(gain)


UNTRUSTED_BLURRED_IN = 0.05


def defocused(image: np.ndarray, targets: np.ndarray, sigma_px: float) -> tuple[np.ndarray, np.ndarray]:
    """The image and composite targets as a camera defocused by one more Gaussian of sigma_px would give
    them. The carrier's numerator and denominator are sums of images, so blurring them is exactly what the
    multi-shot path would measure; the codes keep their phase (the labelled depth's) and take the blurred
    carrier's amplitude, as phase_targets makes them. Untrusted pixels (NaN) stay untrusted, and so do those
    that take more than UNTRUSTED_BLURRED_IN of their light from them (what they show is no longer known)."""

    def blur(a):
        return cv2.GaussianBlur(a, (0, 0), sigma_px, borderType=cv2.BORDER_REFLECT)

    untrusted = blur((~np.isfinite(targets).all(axis=0)).astype(np.float32)) > UNTRUSTED_BLURRED_IN
    carrier = np.stack([blur(np.nan_to_num(t)) for t in targets[:2]])
    codes = targets[2:].reshape(-1, 2, *image.shape)
    phase = np.arctan2(codes[:, 0], codes[:, 1])
    codes = np.hypot(*carrier) * np.stack([np.sin(phase), np.cos(phase)], axis=1)
    targets = np.concatenate([carrier, codes.reshape(-1, *image.shape)])
    targets[:, untrusted] = np.nan
    return blur(image), targets


class FringePhaseSet(Dataset):
    """(image [0, 1], fringe numerator/denominator, r in orders, label mm) tensors at full resolution
    for the phase-aware network; r is the multi-shot phase relative to the calibration's
    reference-depth phase, in fringe orders (NaN where the label is untrusted)."""

    def __init__(self, files, calibration, augment: bool = False, seed: int = 0):
        reference = PhaseOrderDecoder(calibration).reference
        self.items = []
        for f in files:
            image, label, _ = load_sample(f)
            fringe, phase, _ = load_phase_targets(f)
            orders = ((phase - reference) / (2 * np.pi)).astype(np.float32)
            self.items.append((image, fringe.astype(np.float16), orders, label))
        self.augment = augment
        self.rng = np.random.default_rng(seed)

    def __len__(self):
        return len(self.items)

    def __getitem__(self, i):
        image, fringe, orders, label = self.items[i]
        image, fringe = network_input(image), fringe.astype(np.float32)
        if self.augment:
            image, gain = photometric(self.rng, image)
            fringe = fringe * gain
        return (
            torch.from_numpy(image)[None],
            torch.from_numpy(fringe),
            torch.from_numpy(orders)[None],
            torch.from_numpy(label)[None],
        )


class CompositeSet(Dataset):
    """(image [0, 1], carrier and codes' numerators/denominators (2 + 2 x codes, H, W), label mm) tensors for the
    composite network, random crops of crop pixels (0: whole images) when training, placed on the
    network's stride grid (as a whole image is)."""

    def __init__(
        self, files, augment: bool = False, crop: int = 0, seed: int = 0, stride: int = 2, defocus_px: float = 0.0
    ):
        with ThreadPoolExecutor(os.cpu_count()) as pool:  # unzipping runs outside the GIL
            self.items = list(pool.map(self._load, files))
        self.augment, self.crop, self.stride, self.defocus_px = augment, crop, stride, defocus_px
        self.rng = np.random.default_rng(seed)

    @staticmethod
    def _load(f):
        image, label, _ = load_sample(f)
        with np.load(f, allow_pickle=False) as z:
            if "code" not in z:
                raise ValueError(f"{f} has no code targets (make a set with the composite pattern: --set composite)")
            if len(z["code"]) != 2 * len(COMPOSITE_CODES):
                raise ValueError(f"{f} was made for an earlier composite pattern ({len(z['code']) // 2} code gratings)")
            return image, np.concatenate([z["fringe"], z["code"]]), label

    def __len__(self):  # with crops, an epoch still covers about every pixel once
        return len(self.items) * (max(1, self.items[0][0].size // self.crop**2) if self.crop and self.items else 1)

    def __getitem__(self, i):
        image, targets, label = self.items[i % len(self.items)]
        defocus = self.augment and self.defocus_px > 0 and self.rng.random() < 0.5
        sigma = self.rng.uniform(0, self.defocus_px) if defocus else 0.0
        if self.crop:
            y, x = (self.stride * self.rng.integers(0, (n - self.crop) // self.stride + 1) for n in image.shape)
            reach = int(np.ceil(4 * sigma))  # what lies this near the crop blurs into it
            y0, x0 = max(y - reach, 0), max(x - reach, 0)
            window = (slice(y0, y + self.crop + reach), slice(x0, x + self.crop + reach))
            image, targets, label = image[window], targets[(slice(None),) + window], label[window]
            keep = (slice(y - y0, y - y0 + self.crop), slice(x - x0, x - x0 + self.crop))
        image, targets = network_input(image), targets.astype(np.float32)
        if sigma:
            image, targets = defocused(image, targets, sigma)
        if self.crop:
            image, targets, label = image[keep], targets[(slice(None),) + keep], label[keep]
        if self.augment:
            image, gain = photometric(self.rng, image)
            targets = targets * gain
        return torch.from_numpy(image)[None], torch.from_numpy(targets), torch.from_numpy(label)[None]


def reseed_worker(_):
    """Each data-loading process draws its own crops and augmentation (a forked copy of the set's
    generator would repeat the others')."""
    info = torch.utils.data.get_worker_info()
    info.dataset.rng = np.random.default_rng(info.seed)


PHASE_LOSS_FLOOR = 0.02  # full scale: darker labels weigh as this one (the fringe floor export had chosen)
# A pixel whose every target is zero shows no fringes (composite_bars' refused patches): it weighs as a pixel
# of this amplitude. The weight is a dose: 0.1 cost validation 1.8 points of coverage, 0.3 kept it
# (docs/single-shot-trials.md).
REFUSED_AMPLITUDE = 0.3


def composite_loss(pred, targets):
    """Squared error of the numerators/denominators over the pixels whose label is trusted, each
    divided by the carrier's squared amplitude B^2 (at least PHASE_LOSS_FLOOR^2): a vector error e
    moves the phase by about e / B, and the phase is what the depth comes from, so a dark surface's
    fringes count as much as a bright one's. Pixels to refuse (every target zero) weigh as
    REFUSED_AMPLITUDE."""
    valid = torch.isfinite(targets).all(dim=1)
    targets = targets.nan_to_num()
    refused = (targets == 0).all(dim=1)
    amplitude = torch.hypot(targets[:, 0], targets[:, 1]).clamp(min=PHASE_LOSS_FLOOR)
    amplitude = torch.where(refused, REFUSED_AMPLITUDE, amplitude)
    return 10.0 * (((pred - targets) ** 2).sum(dim=1) / amplitude**2)[valid].mean()


LOG_SIGMA_RANGE = (np.log(0.01), np.log(30.0))  # orders


def phase_order_loss(pred, fringe, orders):
    """Squared error of the fringe numerator/denominator, and the Gaussian negative log-likelihood of
    r with the predicted sigma, over the pixels whose multi-shot label is trusted."""
    valid = torch.isfinite(orders[:, 0])
    fringe_error = ((pred[:, :2] - fringe) ** 2).sum(dim=1)[valid].mean()
    log_sigma = pred[:, 3].clamp(*LOG_SIGMA_RANGE)[valid]
    nll = 0.5 * (pred[:, 2][valid] - orders[:, 0][valid]) ** 2 * torch.exp(-2 * log_sigma) + log_sigma
    return 1000.0 * fringe_error + nll.mean()


def masked_loss(pred_mm, label_mm, kind: str):
    valid = torch.isfinite(label_mm)
    if kind == "bce":
        lo, hi = BCE_RANGE_MM
        target = ((label_mm[valid] - lo) / (hi - lo)).clamp(0, 1)
        logits = (pred_mm[valid] - (lo + hi) / 2) / ((hi - lo) / 8)
        return torch.nn.functional.binary_cross_entropy_with_logits(logits, target)
    return torch.mean(((pred_mm[valid] - label_mm[valid]) / 10.0) ** 2)  # in cm^2, a well-scaled number


def predict(model, image):
    padded, (h, w) = pad_to_stride(image)
    return model(padded)[..., :h, :w]


# for the per-epoch numbers only (export chooses the model's threshold): the phase-order network's
# probability that the order is right; the composite's vote
VALIDATION_CONFIDENCE = {"phase": 0.99, "composite": 0.8}
# The validation loss is a mean of per-batch means (each over its batch's trusted pixels), weighted by the
# batch's scenes, so it depends on the batch: validation takes this one whatever the training batch, so
# that runs compare (one network: 0.97 at 8, 0.80 at a GPU run's 32).
VALIDATION_BATCH = 8


@torch.no_grad()
def evaluate_phase(model, loader, device, decoder) -> dict:
    """Loss; RMSE (mm) against the label, coverage of it and the share of pixels off by more than
    1 mm, over the pixels confident at VALIDATION_CONFIDENCE (the phase-order or composite network)."""
    model.eval()
    losses, scenes, errors = [], [], ErrorTotals()
    for image, *targets, label in loader:
        pred = predict(model, image.to(device))
        targets = [t.to(device) for t in targets]
        losses.append(
            (
                composite_loss(pred, *targets)
                if isinstance(decoder, CompositeDecoder)
                else phase_order_loss(pred, *targets)
            ).item()
        )
        scenes.append(len(image))
        for out, ref in zip(pred.cpu().numpy(), label[:, 0].numpy()):
            depth, _ = decoder(
                out, VALIDATION_CONFIDENCE["composite" if isinstance(decoder, CompositeDecoder) else "phase"]
            )
            errors.add(depth, ref, bound=1.0)
    return {
        "loss": float(np.average(losses, weights=scenes)),
        "rmse_mm": errors.rmse,
        "mre": float("nan"),
        "coverage": errors.coverage,
        "silent_errors": errors.share_over,
    }


@torch.no_grad()
def evaluate(model, loader, device, loss_kind: str = "mse") -> dict:
    """Loss, RMSE (mm) and MRE against the labels and against the exact depth."""
    model.eval()
    to_label, to_truth, losses, scenes = ErrorTotals(), ErrorTotals(), [], []
    for image, label, truth in loader:
        pred = predict(model, image.to(device))
        losses.append(masked_loss(pred, label.to(device), loss_kind).item())
        scenes.append(len(image))
        pred = pred.cpu().numpy()
        to_label.add(pred, label.numpy())
        to_truth.add(pred, truth.numpy())
    return {
        "loss": float(np.average(losses, weights=scenes)),
        "rmse_mm": to_label.rmse,
        "mre": to_label.mre,
        "truth_rmse_mm": to_truth.rmse,
        "truth_mre": to_truth.mre,
    }


def save_checkpoint(
    path, model, optimizer, scheduler, config: TrainConfig, epoch: int, history: list, seconds: float, counts: dict
):
    """counts: the training and validation samples it learned from (the set may grow later)."""
    net = model.module if isinstance(model, DistributedDataParallel) else model
    tmp = Path(str(path) + ".tmp")
    torch.save(
        {
            "format": "fpp_checkpoint",
            "version": 1,
            "config": asdict(config),
            "epoch": epoch,
            "model": net.state_dict(),
            "optimizer": optimizer.state_dict(),
            "scheduler": scheduler.state_dict(),
            "history": history,
            "train_seconds": seconds,
            "counts": counts,
        },
        tmp,
    )
    tmp.replace(path)  # never a half-written checkpoint


def load_checkpoint(path) -> dict:
    """A checkpoint of ours, loaded without running any pickled code."""
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:
        raise ValueError(f"cannot load checkpoint {path}: {type(e).__name__}: {str(e).splitlines()[0]}") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != "fpp_checkpoint":
        raise ValueError(f"{path} is not an fpp checkpoint")
    return ckpt


def load_initial_weights(model: torch.nn.Module, path, network: str) -> None:
    """model's weights from where a run starts (optimizer and epochs afresh): a checkpoint, or an
    exported model (.onnx, the shipped one included: its initializers keep the network's names), so
    recordings of a rig can fine-tune the shipped network without its checkpoint. network: what the
    run trains, for the error where path holds another."""
    if Path(path).suffix != ".onnx":
        weights = load_checkpoint(path)["model"]
    else:
        try:
            graph = onnx.load(str(path)).graph
        except Exception as e:
            raise ValueError(f"cannot load model {path}: {type(e).__name__}: {str(e).splitlines()[0]}") from None
        # export writes a composite network inside Strided (net.), cut before its last pixel shuffle
        weights = {
            t.name.removeprefix("net."): torch.from_numpy(numpy_helper.to_array(t).copy()) for t in graph.initializer
        }
    for name, layer in model.named_modules():  # a full convolution where this run has a Separable one
        if isinstance(layer, Separable) and f"{name}.weight" in weights:
            full = weights.pop(f"{name}.weight"), weights.pop(f"{name}.bias")
            weights |= {f"{name}.{k}": v for k, v in Separable.factored(*full, len(layer.terms)).items()}
    expected = model.state_dict()
    wrong = [k for k in expected if k not in weights or weights[k].shape != expected[k].shape]
    if wrong:
        raise ValueError(
            f"{path} holds another network than this run's ({network}): nothing or another shape for "
            + ", ".join(wrong[:3])
            + (" ..." if len(wrong) > 3 else "")
        )
    model.load_state_dict({k: weights[k] for k in expected})


def model_from_config(config: dict):
    """(an untrained network, its TrainConfig) of a run's config: a checkpoint's, or a model card's training.config."""
    cfg = TrainConfig(**{k: v for k, v in config.items() if k in {f.name for f in fields(TrainConfig)}})
    return cfg.network(), cfg


def model_from_checkpoint(ckpt: dict):
    model, cfg = model_from_config(ckpt["config"])
    model.load_state_dict(ckpt["model"])
    return model.eval(), cfg


def write_curves(out: Path, history: list) -> None:
    with open(out / "losses.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(history[0]))
        writer.writeheader()
        writer.writerows(history)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    epochs = [h["epoch"] for h in history]
    ax.plot(epochs, [h["train_loss"] for h in history], label="train loss")
    ax.plot(epochs, [h["val_loss"] for h in history], label="validation loss")
    ax.set_yscale("log")
    ax.set_xlabel("epoch")
    ax.legend()
    ax2 = ax.twinx()
    ax2.plot(epochs, [h["val_rmse_mm"] for h in history], "k:", label="validation RMSE")
    ax2.set_ylabel("validation RMSE vs label (mm)")
    fig.tight_layout()
    fig.savefig(out / "losses.png", dpi=100)
    plt.close(fig)


def train(config: TrainConfig, resume: str | None = None) -> dict:
    distributed = int(os.environ.get("WORLD_SIZE", "1")) > 1
    if distributed:
        dist.init_process_group("nccl" if torch.cuda.is_available() else "gloo")
    rank = dist.get_rank() if distributed else 0
    device = torch.device(f"cuda:{int(os.environ.get('LOCAL_RANK', 0))}" if torch.cuda.is_available() else "cpu")
    torch.manual_seed(config.seed)
    torch.backends.cudnn.benchmark = True  # fixed crop sizes: let cuDNN pick its fastest kernels
    out = Path(config.out)
    if rank == 0:
        (out / "epochs").mkdir(parents=True, exist_ok=True)

    train_files = split_files(config.data, "train")[: config.limit or None]
    val_files = split_files(config.data, "val")
    if not train_files or not val_files:
        raise ValueError(f"{config.data} has no train or val samples (make them with python -m training.dataset)")
    calibration = sets_calibration([config.data, *([config.extra] if config.extra else [])])
    if config.extra:
        train_files += split_files(config.extra, "train")
    counts = {"train": len(train_files), "val": len(val_files)}
    if not config.depth_offset_mm:  # the set's rig, not the simulated one: a network starts near its depths
        config = replace(config, depth_offset_mm=calibration.reference_depth_mm)
    phase_aware = config.arch in ("phase", "composite")
    if phase_aware:
        if config.arch == "composite":
            decoder = CompositeDecoder(calibration)
            train_set = CompositeSet(
                train_files, config.augment, config.crop, config.seed + rank, config.stride, config.defocus_px
            )
            val_set = CompositeSet(val_files)
        else:
            decoder = PhaseOrderDecoder(calibration)
            train_set = FringePhaseSet(train_files, calibration, config.augment, config.seed + rank)
            val_set = FringePhaseSet(val_files, calibration)
    else:
        train_set = FringeDepthSet(train_files, config.downsample, config.augment, config.seed + rank)
        val_set = FringeDepthSet(val_files, config.downsample)
    sampler = DistributedSampler(train_set, seed=config.seed) if distributed else None
    loader = DataLoader(
        train_set,
        config.batch_size,
        shuffle=sampler is None,
        sampler=sampler,
        num_workers=config.workers,
        worker_init_fn=reseed_worker,
        persistent_workers=config.workers > 0,
    )
    val_loader = DataLoader(val_set, VALIDATION_BATCH)
    showcase = val_set[0]  # one fixed validation image

    model = config.network().to(device)
    optimizer = torch.optim.AdamW(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    scheduler = torch.optim.lr_scheduler.ReduceLROnPlateau(optimizer, factor=0.5, patience=config.patience)
    history, start_epoch, seconds = [], 0, 0.0
    if config.init and not resume:
        load_initial_weights(model, config.init, f"{config.arch}, width {config.width}")
    if resume:
        ckpt = load_checkpoint(resume)
        model.load_state_dict(ckpt["model"])
        optimizer.load_state_dict(ckpt["optimizer"])
        scheduler.load_state_dict(ckpt["scheduler"])
        history, start_epoch, seconds = ckpt["history"], ckpt["epoch"], ckpt["train_seconds"]
    if distributed:
        model = DistributedDataParallel(model)
    # a composite network reads every rig's frames laid out as the simulated rig's (a set from another rig's bags)
    layout = network_layout(calibration) if config.arch == "composite" else Layout()
    laid_out = LaidOut(model, layout)

    best = min((h["val_loss"] for h in history), default=float("inf"))
    for epoch in range(start_epoch + 1, config.epochs + 1):
        started = time.perf_counter()
        model.train()
        if sampler is not None:
            sampler.set_epoch(epoch)
        total, batches = 0.0, 0
        for image, *targets in tqdm(
            loader, desc=f"epoch {epoch}/{config.epochs}", leave=False, disable=None if rank == 0 else True
        ):
            optimizer.zero_grad()
            pred = predict(laid_out, image.to(device))
            if config.arch == "composite":
                loss = composite_loss(pred, targets[0].to(device))
            elif phase_aware:
                loss = phase_order_loss(pred, *(t.to(device) for t in targets[:2]))
            else:
                loss = masked_loss(pred, targets[0].to(device), config.loss)
            loss.backward()
            optimizer.step()
            total, batches = total + loss.item(), batches + 1
        seconds += time.perf_counter() - started
        metrics = (
            evaluate_phase(laid_out, val_loader, device, decoder)
            if phase_aware
            else evaluate(model, val_loader, device, config.loss)
        )
        val_loss = metrics["loss"]
        scheduler.step(val_loss)
        if rank != 0:
            continue
        history.append(
            {
                "epoch": epoch,
                "train_loss": total / max(batches, 1),
                "val_loss": val_loss,
                "val_rmse_mm": metrics["rmse_mm"],
                "val_mre": metrics["mre"],
                **{f"val_{k}": metrics[k] for k in ("coverage", "silent_errors") if k in metrics},
                "lr": optimizer.param_groups[0]["lr"],
                "seconds": seconds,
            }
        )
        net = model.module if distributed else model
        net.eval()
        with torch.no_grad():
            shown = predict(LaidOut(net, layout), showcase[0][None].to(device))[0].cpu().numpy()
        shown = decoder(shown, VALIDATION_CONFIDENCE[config.arch])[0] if phase_aware else shown[0]
        cv2.imwrite(
            str(out / "epochs" / f"epoch_{epoch:04d}.png"),
            np.hstack([depth_colours(showcase[-1 if phase_aware else 1][0].numpy()), depth_colours(shown)]),
        )
        save_checkpoint(out / "last.pt", model, optimizer, scheduler, config, epoch, history, seconds, counts)
        if val_loss < best:
            best = val_loss
            save_checkpoint(out / "best.pt", model, optimizer, scheduler, config, epoch, history, seconds, counts)
        write_curves(out, history)
        extra = f", coverage {metrics['coverage']:.1%}, > 1 mm {metrics['silent_errors']:.2%}" if phase_aware else ""
        print(
            f"epoch {epoch}: train loss {history[-1]['train_loss']:.4g}, val loss {val_loss:.4g}, "
            f"val RMSE {metrics['rmse_mm']:.3f} mm{extra}, lr {history[-1]['lr']:.2g}, {seconds:.0f} s",
            flush=True,
        )
    if distributed:
        dist.destroy_process_group()
    return history[-1] if history else {}


def main(argv=None):
    parser = argparse.ArgumentParser(
        prog="python -m training.train", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    for f in fields(TrainConfig):
        kind = {"bool": lambda s: s.lower() in ("1", "true", "yes")}.get(
            f.type, {"int": int, "float": float}.get(f.type, str)
        )
        parser.add_argument(f"--{f.name.replace('_', '-')}", type=kind, default=f.default)
    parser.add_argument("--resume", help="a last.pt to go on from")
    args = vars(parser.parse_args(argv))
    resume = args.pop("resume")
    try:
        train(TrainConfig(**args), resume)
    except ValueError as e:
        raise SystemExit(f"train: error: {e}") from None


if __name__ == "__main__":
    main()
