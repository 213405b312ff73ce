"""The paper's three networks as small named blocks, so each forward reads like its figure.

All take a (B, 1, H, W) fringe image scaled to [0, 1] (H, W multiples of 32), add two pixel-coordinate
channels (u and v in [-1, 1] across the image: depth depends on where a pixel is, through the phase-
to-depth model), and return (B, 1, H, W) depth in millimetres: the last layer's output o becomes
depth_offset + depth_scale * o, so the exported model speaks millimetres.

- AEN: encoder of 5 levels (two 3x3 convolutions, then 2x2 max-pooling), two convolutions at the
  bottom, decoder of 5 levels (a 2x2 transpose convolution, then two convolutions), a final 1x1
  convolution: 22 convolutions, 5 max-pools, 5 transpose convolutions, 1 output layer = 33 layers.
- UNet: the AEN with each encoder level's output concatenated to the decoder's at the same scale.
- FCN: a VGG-style encoder with no fully connected layers (fc6/fc7 as convolutions), scored at 1/8,
  1/16 and 1/32 scale, the coarse score upsampled and summed with the finer ones (FCN-8s), then
  upsampled 8x to the input size.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from fpp_nodes.core.patterns import COMPOSITE_CODES


class DoubleConv(nn.Sequential):
    def __init__(self, cin: int, cout: int, dropout: float = 0.0):
        layers = [
            nn.Conv2d(cin, cout, 3, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv2d(cout, cout, 3, padding=1),
            nn.ReLU(inplace=True),
        ]
        if dropout:
            layers.append(nn.Dropout2d(dropout))
        super().__init__(*layers)


class Down(nn.Sequential):
    def __init__(self, cin: int, cout: int):
        super().__init__(nn.MaxPool2d(2), DoubleConv(cin, cout))


class Up(nn.Module):
    """Transpose convolution to twice the size, optionally concatenated with the skip, two convolutions."""

    def __init__(self, cin: int, cout: int, skip: int = 0):
        super().__init__()
        self.up = nn.ConvTranspose2d(cin, cout, 2, stride=2)
        self.conv = DoubleConv(cout + skip, cout)

    def forward(self, x, skip=None):
        x = self.up(x)
        return self.conv(x if skip is None else torch.cat([x, skip], dim=1))


def with_coordinates(image: torch.Tensor) -> torch.Tensor:
    b, _, h, w = image.shape
    v = torch.linspace(-1.0, 1.0, h, dtype=image.dtype, device=image.device).view(1, 1, h, 1).expand(b, 1, h, w)
    u = torch.linspace(-1.0, 1.0, w, dtype=image.dtype, device=image.device).view(1, 1, 1, w).expand(b, 1, h, w)
    return torch.cat([image, u, v], dim=1)


class DepthHead(nn.Module):
    """1x1 convolution to one channel, then millimetres."""

    def __init__(self, cin: int, depth_offset: float, depth_scale: float):
        super().__init__()
        self.out = nn.Conv2d(cin, 1, 1)
        self.depth_offset, self.depth_scale = depth_offset, depth_scale

    def forward(self, x):
        return self.depth_offset + self.depth_scale * self.out(x)


class EncoderDecoder(nn.Module):
    """AEN (skips=False) and UNet (skips=True): the same shape, with or without concatenation."""

    def __init__(self, width: int, skips: bool, dropout: float, depth_offset: float, depth_scale: float):
        super().__init__()
        c = [width * 2**i for i in range(6)]  # channels at full, 1/2, ... 1/32 scale
        self.skips = skips
        self.inc = DoubleConv(3, c[0])
        self.downs = nn.ModuleList(Down(c[i], c[i + 1]) for i in range(4))
        self.bottom = nn.Sequential(nn.MaxPool2d(2), DoubleConv(c[4], c[5], dropout))
        self.ups = nn.ModuleList(Up(c[i + 1], c[i], c[i] if skips else 0) for i in reversed(range(5)))
        self.head = DepthHead(c[0], depth_offset, depth_scale)

    def forward(self, image):
        x = self.inc(with_coordinates(image))
        levels = [x]
        for down in self.downs:
            x = down(x)
            levels.append(x)
        x = self.bottom(x)
        for up, skip in zip(self.ups, reversed(levels)):
            x = up(x, skip if self.skips else None)
        return self.head(x)


class FCN(nn.Module):
    """FCN-8s for regression: VGG-style blocks, convolutional fc6/fc7, skip sums, coarse upsampling."""

    def __init__(self, width: int, dropout: float, depth_offset: float, depth_scale: float):
        super().__init__()
        c = [width * 2 ** min(i, 4) for i in range(5)]
        self.block1 = DoubleConv(3, c[0])
        self.block2 = Down(c[0], c[1])
        self.block3 = Down(c[1], c[2])  # 1/4
        self.block4 = Down(c[2], c[3])  # 1/8
        self.block5 = Down(c[3], c[4])  # 1/16
        self.fc = nn.Sequential(
            nn.MaxPool2d(2),
            nn.Conv2d(c[4], 2 * c[4], 3, padding=1),
            nn.ReLU(inplace=True),
            nn.Dropout2d(dropout),
            nn.Conv2d(2 * c[4], 2 * c[4], 1),
            nn.ReLU(inplace=True),
        )  # 1/32
        score = c[2]
        self.score32 = nn.Conv2d(2 * c[4], score, 1)
        self.score16 = nn.Conv2d(c[4], score, 1)
        self.score8 = nn.Conv2d(c[3], score, 1)
        self.up2a = nn.ConvTranspose2d(score, score, 2, stride=2)
        self.up2b = nn.ConvTranspose2d(score, score, 2, stride=2)
        self.up8 = nn.ConvTranspose2d(score, score, 8, stride=8)
        self.head = DepthHead(score, depth_offset, depth_scale)

    def forward(self, image):
        x8 = self.block4(self.block3(self.block2(self.block1(with_coordinates(image)))))
        x16 = self.block5(x8)
        x = self.up2a(self.score32(self.fc(x16))) + self.score16(x16)
        x = self.up2b(x) + self.score8(x8)
        return self.head(torch.relu(self.up8(x)))


class PhaseOrderNet(nn.Module):
    """Phase-aware single shot (after Feng et al. 2019): accuracy from the fringe, order from context.

    The phase branch sees a few fringe periods around each pixel (stride-2 features, a pixel shuffle
    back to full resolution) and predicts the numerator and denominator of the highest frequency's
    wrapped phase (B sin phi, B cos phi, in full-scale units). The order branch is a UNet at 1/4
    resolution over what the phase says and where: the local phase steps along u and v (their sine and
    cosine, smooth where the fringes are not), the fringe amplitude, the mean level and the pixel
    coordinates. It predicts r, the absolute phase relative to the calibration's reference-depth phase
    in fringe orders, and log sigma, the standard deviation it expects of r: large where one image
    cannot tell the order (an isolated surface, a step), so such pixels become NaN, never a guess.
    Output (B, 4, H, W): numerator, denominator, r, log sigma.
    """

    def __init__(self, width: int = 16, phase_width: int = 16):
        super().__init__()
        p = phase_width
        self.phase = nn.Sequential(
            nn.Conv2d(1, p, 6, stride=2, padding=2),
            nn.ReLU(inplace=True),
            nn.Conv2d(p, p, 3, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv2d(p, p, 3, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv2d(p, 8, 1),
            nn.PixelShuffle(2),
        )
        c = [width * 2**i for i in range(4)]
        self.inc = DoubleConv(8, c[0])
        self.downs = nn.ModuleList(Down(c[i], c[i + 1]) for i in range(3))
        self.ups = nn.ModuleList(Up(c[i + 1], c[i], c[i]) for i in reversed(range(3)))
        self.order = nn.Conv2d(c[0], 2, 1)

    @staticmethod
    def phase_steps(num, den):
        """sin and cos of the wrapped-phase step to the next pixel along u and along v."""

        def step(n0, d0, n1, d1):
            sin, cos = n1 * d0 - d1 * n0, n1 * n0 + d1 * d0
            norm = torch.sqrt(sin * sin + cos * cos + 1e-8)
            return sin / norm, cos / norm

        su, cu = step(num[..., :-1], den[..., :-1], num[..., 1:], den[..., 1:])
        sv, cv = step(num[..., :-1, :], den[..., :-1, :], num[..., 1:, :], den[..., 1:, :])
        pad_u, pad_v = (0, 1, 0, 0), (0, 0, 0, 1)
        return [nn.functional.pad(t, pad_u, mode="replicate") for t in (su, cu)] + [
            nn.functional.pad(t, pad_v, mode="replicate") for t in (sv, cv)
        ]

    def forward(self, image):
        fringe = self.phase(image)
        num, den = fringe[:, :1], fringe[:, 1:]
        amplitude = torch.sqrt(num * num + den * den)
        # the order branch reads the phase, it does not train it
        features = torch.cat(self.phase_steps(num.detach(), den.detach()) + [amplitude.detach(), image], dim=1)
        x = self.inc(with_coordinates(nn.functional.avg_pool2d(features, 4)))
        levels = [x]
        for down in self.downs:
            x = down(x)
            levels.append(x)
        for up, skip in zip(self.ups, reversed(levels[:-1])):
            x = up(x, skip)
        order = nn.functional.interpolate(self.order(x), scale_factor=4, mode="bilinear", align_corners=False)
        return torch.cat([fringe, order], dim=1)


class Separable(nn.Module):
    """A 3 x 3 convolution of C channels as the sum of rank separable ones, each a 3 x 3 per channel
    (depthwise) then a 1 x 1 mixing them (pointwise): rank x (9 + C) / 9C of its multiply-adds, a sixth
    at 16 channels and rank 1. (One depthwise layer of rank x C channels would be the same function,
    but onnxruntime runs it as slowly as the full convolution: only C -> C depthwise has its fast path.)"""

    def __init__(self, channels: int, dilation: int, rank: int = 1):
        super().__init__()
        self.terms = nn.ModuleList(
            nn.Sequential(
                nn.Conv2d(channels, channels, 3, padding=dilation, dilation=dilation, groups=channels),
                nn.Conv2d(channels, channels, 1),
            )
            for _ in range(rank)
        )

    def forward(self, x):
        y = self.terms[0](x)
        for term in self.terms[1:]:
            y = y + term(x)
        return y

    @staticmethod
    def factored(weight: torch.Tensor, bias: torch.Tensor, rank: int = 1) -> dict:
        """Its weights nearest a full 3 x 3 convolution's (weight (C, C, 3, 3), bias), to start from a
        trained network: per input channel, the best sum of rank products (least squares, the SVD's first
        terms) of a column of output weights and one 3 x 3 kernel; exact where the full one's kernels of
        each input channel span no more than rank kernels."""
        outputs, inputs = weight.shape[:2]
        # per input channel i: its kernels (outputs x 9) = sum over k of u[i, :, k] s[i, k] vh[i, k]
        u, s, vh = torch.linalg.svd(weight.transpose(0, 1).reshape(inputs, outputs, 9), full_matrices=False)
        weights = {}
        for k in range(rank):
            weights |= {
                f"terms.{k}.0.weight": vh[:, k].reshape(inputs, 1, 3, 3),
                f"terms.{k}.0.bias": torch.zeros(inputs),
                f"terms.{k}.1.weight": (u[:, :, k] * s[:, k, None]).T.reshape(outputs, inputs, 1, 1),
                f"terms.{k}.1.bias": bias if k == 0 else torch.zeros(outputs),
            }
        return weights


class CompositeNet(nn.Module):
    """The composite pattern's fringe analyser: from one image, the numerators and denominators of the
    carrier's and the code gratings' phases (B sin, B cos in full-scale units), each from the few
    fringe periods around the pixel (strided features, dilated convolutions for about 40-50 pixels,
    a pixel shuffle back to full resolution), with a context branch at 1/8 resolution that sees about
    150 pixels around (what the image's texture is, beyond one fringe period: on validation it lowered
    the loss by a tenth and raised the coverage by 0.9-1.5 points, docs/single-shot.md). It learns to read
    fringes, not scenes: the fringe order and the depth follow from physics
    (fpp_nodes.core.model.CompositeDecoder).
    stride: the first layer's, undone at the end by a pixel shuffle (export leaves that to DepthModel):
    2, or 4 for a quarter of the pixels to convolve (docs/single-shot-trials.md, the network at a quarter of
    the resolution). separable: how many of the last middle layers are Separable, each the sum of
    separable_rank separable ones (a lead for slower CPUs: docs/single-shot-trials.md, separable layers).
    Output (B, 2 x gratings, H, W): carrier numerator, denominator, then each code's (the composite's
    gratings: its carrier and patterns.COMPOSITE_CODES; training/compare_codes.py tries others).
    """

    DILATIONS = {2: (1, 2, 4, 2), 4: (1, 1, 2, 1)}  # by stride: fields of 42 and 52 pixels

    def __init__(
        self,
        width: int = 16,
        gratings: int = 1 + len(COMPOSITE_CODES),
        stride: int = 2,
        separable: int = 0,
        separable_rank: int = 1,
    ):
        super().__init__()
        if stride not in self.DILATIONS:
            raise ValueError(f"stride must be one of {sorted(self.DILATIONS)}, got {stride}")
        dilations = self.DILATIONS[stride]
        if not 0 <= separable <= len(dilations):
            raise ValueError(f"separable must be 0-{len(dilations)} (of the middle layers), got {separable}")
        p, self.pixel_shuffle = width, stride
        layers = [nn.Conv2d(1, p, 3 * stride, stride=stride, padding=stride), nn.ReLU(inplace=True)]
        for i, dilation in enumerate(dilations):
            if i < len(dilations) - separable:
                layers += [nn.Conv2d(p, p, 3, padding=dilation, dilation=dilation)]
            else:
                layers += [Separable(p, dilation, separable_rank)]
            layers += [nn.ReLU(inplace=True)]
        self.net = nn.Sequential(*layers, nn.Conv2d(p, 2 * gratings * stride * stride, 1))
        self.context = nn.Sequential(
            nn.AvgPool2d(8 // stride),
            nn.Conv2d(p, p, 3, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv2d(p, p, 3, padding=2, dilation=2),
            nn.ReLU(inplace=True),
            nn.Identity(),  # the upsampling's first place: the 1x1 keeps its key (context.6) in older checkpoints
            nn.Conv2d(p, p, 1),  # zero at the start: the branch adds nothing until it has learned something
            # after the 1x1: bilinear weights sum to one, so the function is the same at 1/16 of the cost
            nn.Upsample(scale_factor=8 // stride, mode="bilinear"),  # sizes are multiples of 32 (pad_to_stride)
        )
        nn.init.zeros_(self.context[6].weight)
        nn.init.zeros_(self.context[6].bias)

    def strided(self, image):
        """The outputs before the pixel shuffle back to full resolution: stride^2 times the channels at
        1/stride of the resolution. Export writes this (the card says pixel_shuffle) and DepthModel
        shuffles in numpy: onnxruntime's DepthToSpace took 6 of a 640x480 frame's 30 ms on an AVX2
        core, numpy 1."""
        first = self.net[:2](image)
        return self.net[2:](first + self.context(first))

    def forward(self, image):
        return nn.functional.pixel_shuffle(self.strided(image), self.pixel_shuffle)


class LaidOut(nn.Module):
    """A composite network shown a rig's frames (B, 1, H, W) laid out as DepthModel shows them
    (fpp_nodes.core.model.network_layout: as the simulated rig's, which every network is trained on), its
    outputs turned back to the rig's: a set recorded on a rig with its projector above the camera, its
    camera turned or rolled or its projector mirrored trains and is judged as cnn_depth runs it."""

    def __init__(self, net: nn.Module, layout):
        super().__init__()
        self.net, self.layout = net, layout

    def forward(self, image):
        axes = [axis - 2 for axis in self.layout.flipped]  # the frame's axes (0: up-down) as the tensor's last two
        x = image.transpose(-2, -1) if self.layout.transposed else image
        x = x.flip(axes) if axes else x
        upright = (x.shape[-1], x.shape[-2])
        if self.layout.turned_deg:
            matrix, canvas = self.layout.turn(upright)
            x = warped(x, np.linalg.inv(np.vstack([matrix, (0, 0, 1)])), canvas)
        padded, (h, w) = pad_to_stride(x)
        out = self.net(padded)[..., :h, :w]
        out = warped(out, matrix, upright) if self.layout.turned_deg else out
        out = out.flip(axes) if axes else out
        return out.transpose(-2, -1) if self.layout.transposed else out


def warped(x: torch.Tensor, matrix: np.ndarray, size: tuple[int, int]) -> torch.Tensor:
    """x (B, C, H, W) at size (width, height), each pixel p bilinearly sampled at matrix [p, 1] (2 x 3 or 3 x
    3: cv2.warpAffine's with WARP_INVERSE_MAP, the border replicated); differentiable."""
    w, h = size
    ys, xs = torch.meshgrid(torch.arange(h, dtype=x.dtype), torch.arange(w, dtype=x.dtype), indexing="ij")
    m = torch.as_tensor(np.asarray(matrix)[:2], dtype=x.dtype)
    at_x, at_y = (m[i, 0] * xs + m[i, 1] * ys + m[i, 2] for i in (0, 1))
    # align_corners: -1 and 1 are the first and last pixels' centres
    grid = torch.stack([2 * at_x / (x.shape[-1] - 1) - 1, 2 * at_y / (x.shape[-2] - 1) - 1], dim=-1)
    grid = grid.to(x.device).expand(x.shape[0], h, w, 2)
    return nn.functional.grid_sample(x, grid, mode="bilinear", padding_mode="border", align_corners=True)


ARCHITECTURES = ("fcn", "aen", "unet", "phase", "composite")


def build(
    architecture: str,
    width: int,
    dropout: float,
    depth_mm: tuple[float, float],
    stride: int = 2,
    separable: int = 0,
    separable_rank: int = 1,
) -> nn.Module:
    """depth_mm: (offset, scale) of the depth-regressing networks' output in millimetres (the training
    config holds them, so checkpoints do); stride, separable and separable_rank: the composite network's."""
    depth_offset, depth_scale = depth_mm
    if architecture == "unet":
        return EncoderDecoder(width, True, dropout, depth_offset, depth_scale)
    if architecture == "aen":
        return EncoderDecoder(width, False, dropout, depth_offset, depth_scale)
    if architecture == "fcn":
        return FCN(width, dropout, depth_offset, depth_scale)
    if architecture == "phase":
        return PhaseOrderNet(width)
    if architecture == "composite":
        return CompositeNet(width, stride=stride, separable=separable, separable_rank=separable_rank)
    raise ValueError(f"architecture must be one of {', '.join(ARCHITECTURES)}, got {architecture!r}")


def layer_counts(model: nn.Module) -> dict:
    kinds = {"conv": nn.Conv2d, "maxpool": nn.MaxPool2d, "transpose": nn.ConvTranspose2d}
    return {
        k: sum(
            isinstance(m, t) and not isinstance(m, nn.ConvTranspose2d) if k == "conv" else isinstance(m, t)
            for m in model.modules()
        )
        for k, t in kinds.items()
    }


STRIDE = 32  # every network halves the image five times


def pad_to_stride(image: torch.Tensor, stride: int = STRIDE) -> tuple[torch.Tensor, tuple[int, int]]:
    """Replicate-pad (B, C, H, W) on the bottom and right to multiples of stride; returns the padded
    image and the original (H, W) to crop the output back to."""
    h, w = image.shape[-2:]
    return nn.functional.pad(image, (0, (-w) % stride, 0, (-h) % stride), mode="replicate"), (h, w)
