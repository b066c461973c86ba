"""Visual foresight (VF): predict the next RGB-H image after a pick-and-place action.

Action encoding (9 channels, all on the unpadded 160 x 160 grid):

* 0-3: the current normalised RGB-H;
* 4: pick mask, ones on the ``window`` x ``window`` square centred at the pick pixel
  (rows ``pick_row - window/2 .. pick_row + window/2 - 1``, likewise columns, as the reference);
* 5-8: place mask, the same square around the pick cut from the RGB-H image, its content turned by
  the place yaw change (world yaw, geometry's convention: content motion ``p' = R(yaw)(p - pick) + place``
  in (col, row)) and pasted centred at the place pixel; zero (= mean value) elsewhere.

The place mask is one :func:`tvf.geometry.warp_images` call (rotate about the pick and translate to the
place, nearest neighbour) multiplied by the window mask at the place pixel. Content from outside the
image is zero (mean value), which equals the reference's 22 px zero padding. The FCN input may then be
zero-padded by ``preset.vf_pad`` (the reference pads 22 px) and its output is cropped back, so the loss
only sees the real 160 x 160 image.

By default the network predicts the next image directly, as the reference. ``preset.vf_residual``
switches to next = input RGB-H + FCN(encoding); on a fixed batch of synthetic block moves the residual
head sat longer on the copy-the-input plateau (L1 pulls every unchanged pixel's change to zero) and
ended higher (0.068 vs 0.042 after 400 steps; copying scores 0.116), so it is off by default.

``preset.vf_head = "blend"`` makes the network edit its input instead: three more output channels are
per-pixel logits of a softmax over (keep the input, take the pasted place window, take the redrawn
value), and next = w_keep * input + w_paste * pasted + w_draw * FCN. Pixels the action does not touch
can keep their input exactly, so errors do not pile up when the model is fed its own predictions.
``preset.vf_head = "local"`` keeps every pixel outside the pick and place windows exactly as the input
and takes the FCN's image inside them (:func:`local_output`): a local predictor that cannot blur or
drift where the action did nothing.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

from tvf.geometry import se2_output_to_input, warp_images
from tvf.models.backbone import resnet36_4s
from tvf.models.images import MAX_HEIGHT, RGBH_CHANNELS, ArrayLike, as_pixels, clamp_rgbh, from_rgbh, to_rgbh
from tvf.models.presets import ModelPreset

ACTION_CHANNELS = 2 * RGBH_CHANNELS + 1
HEIGHT_WEIGHT = 5.0
INFERENCE_CHUNK = 4
"""Largest batch predicted at once. With one thread per process and another process beside it (the
evaluation set-up), lite took 18 / 13 / 20 / 16 / 28 ms per image at chunks 1 / 4 / 8 / 16 / 27."""
ACCELERATOR_CHUNK = 64
"""Largest batch predicted at once on a GPU (several environments' tree levels, `tvf eval
--envs-per-worker`); not tuned yet: no GPU was lent so far."""


def square_masks(centres: torch.Tensor, window: int, height: int, width: int) -> torch.Tensor:
    """(B, 1, H, W) float masks, ones on rows ``c_row - window/2 .. c_row + window/2 - 1`` (same for cols)."""
    half = window // 2
    rows = torch.arange(height, device=centres.device)
    cols = torch.arange(width, device=centres.device)
    in_rows = (rows >= centres[:, :1] - half) & (rows < centres[:, :1] + half)  # (B, H)
    in_cols = (cols >= centres[:, 1:] - half) & (cols < centres[:, 1:] + half)  # (B, W)
    return (in_rows[:, None, :, None] & in_cols[:, None, None, :]).to(torch.float32)


def moved_to_place(images: torch.Tensor, pick: torch.Tensor, place: torch.Tensor, yaws: ArrayLike
                   ) -> torch.Tensor:  # fmt: skip
    """``images`` (B, C, H, W) with their content turned by ``yaws`` (B,) about ``pick`` and moved to
    ``place`` ((B, 2) int64 row, col), nearest neighbour: the picked block's motion, ``p' = R(yaw)(p -
    pick) + place`` in (col, row). Content from outside the image is zero."""
    pick_f = pick.to(torch.float32).cpu()
    out_to_in = se2_output_to_input(
        torch.as_tensor(yaws, dtype=torch.float32).cpu(), pick_f, place.to(torch.float32).cpu() - pick_f
    )
    return warp_images(images, out_to_in, mode="nearest")


def encode_action(
    rgbh: torch.Tensor, pick: torch.Tensor, place: torch.Tensor, yaws: torch.Tensor, window: int = 44
) -> torch.Tensor:
    """Normalised RGB-H (B, 4, H, W) + action -> the 9-channel VF input (B, 9, H, W).

    ``pick``/``place`` (B, 2) int64 (row, col); ``yaws`` (B,) place yaw change in radians.
    """
    h, w = rgbh.shape[-2:]
    moved = moved_to_place(rgbh, pick, place, yaws)
    pick_mask = square_masks(pick, window, h, w).to(rgbh.dtype)
    place_mask = square_masks(place, window, h, w).to(rgbh.dtype)
    return torch.cat([rgbh, pick_mask, moved * place_mask], dim=1)


BLEND_SOURCES = ("keep", "paste", "draw")
"""The blend head's per-pixel choices, in the order of its logit channels."""


def paste_place_window(
    rgbh: torch.Tensor, encoding: torch.Tensor, place: torch.Tensor, window: int
) -> torch.Tensor:
    """The input with the moved pick window of ``encoding`` (:func:`encode_action`) pasted at the place:
    the no-learning prediction (B, 4, H, W)."""
    mask = square_masks(place, window, *rgbh.shape[-2:]).to(rgbh.dtype)
    return rgbh * (1 - mask) + encoding[:, RGBH_CHANNELS + 1 :] * mask


def blend_output(
    rgbh: torch.Tensor, encoding: torch.Tensor, y: torch.Tensor, place: torch.Tensor, window: int
) -> torch.Tensor:
    """The blend head's image: softmax-weighted input, pasted window and drawn value (B, 4, H, W)."""
    pasted = paste_place_window(rgbh, encoding, place, window)
    weights = torch.softmax(y[:, RGBH_CHANNELS:], dim=1)
    return weights[:, :1] * rgbh + weights[:, 1:2] * pasted + weights[:, 2:3] * y[:, :RGBH_CHANNELS]


def local_output(rgbh: torch.Tensor, drawn: torch.Tensor, pick: torch.Tensor, place: torch.Tensor,
                 window: int) -> torch.Tensor:  # fmt: skip
    """The local head's image: the FCN's ``drawn`` inside the pick and place windows, the input elsewhere."""
    h, w = rgbh.shape[-2:]
    mask = torch.maximum(square_masks(pick, window, h, w), square_masks(place, window, h, w)).to(rgbh.dtype)
    return rgbh * (1 - mask) + drawn * mask


def vf_loss(
    predicted: torch.Tensor, target: torch.Tensor, pixel_weights: torch.Tensor | None = None
) -> torch.Tensor:
    """L1 on normalised RGB-H, height weighted x5: mean over pixels of (|dR|+|dG|+|dB|+5|dH|) / 4.

    ``pixel_weights`` (B, H, W), when given, multiplies each pixel's term (:func:`changed_pixel_weights`);
    None is the reference's loss.
    """
    weights = torch.tensor([1.0, 1.0, 1.0, HEIGHT_WEIGHT], device=predicted.device, dtype=predicted.dtype)
    per_pixel = ((predicted - target).abs() * weights.view(1, 4, 1, 1)).sum(dim=1)
    if pixel_weights is not None:
        per_pixel = per_pixel * pixel_weights.to(per_pixel)
    return per_pixel.mean() / RGBH_CHANNELS


CHANGED_MM = 5.0
"""A pixel whose true height moves by more than this (mm) between two images changed: the pixels the
changed-pixel loss weighs and `tvf eval-vf`'s changed-pixel error counts."""


def height_changed(before: torch.Tensor, after: torch.Tensor) -> torch.Tensor:
    """Bool mask of the pixels whose height (metres) moved by more than :data:`CHANGED_MM`."""
    return (torch.as_tensor(after) - torch.as_tensor(before)).abs() * 1000 > CHANGED_MM


def changed_pixel_weights(
    current_height: torch.Tensor, next_height: torch.Tensor, extra: float
) -> torch.Tensor:
    """Per-pixel loss weights (B, H, W): 1 everywhere, ``1 + extra`` where :func:`height_changed` (the
    picked block's old and new footprint: about 1 % of the image, yet all the search looks at)."""
    return 1.0 + extra * height_changed(current_height, next_height).to(torch.float32)


class ImagePredictor:
    """Inference of a network called as ``model(rgbh, pick, place, yaws) -> next normalised RGB-H``: in
    chunks of :attr:`inference_chunk`, without gradients, clamped to physical ranges. The VF and the
    latent-dynamics baseline share it (the interface the planner and `tvf eval-vf` use)."""

    inference_chunk = INFERENCE_CHUNK

    @torch.no_grad()
    def _predict_chunked(
        self, rgbh: torch.Tensor, pick_pixels: ArrayLike, place_pixels: ArrayLike, yaws: ArrayLike
    ) -> torch.Tensor:
        """Unclamped prediction in chunks of :attr:`inference_chunk` (faster than one big batch on CPU;
        :data:`ACCELERATOR_CHUNK` on a GPU)."""
        b = rgbh.shape[0]
        pick = as_pixels(pick_pixels, b)
        place = as_pixels(place_pixels, b)
        yaws = torch.as_tensor(yaws, dtype=torch.float32).reshape(-1).expand(b)
        step = (
            self.inference_chunk
            if rgbh.device.type == "cpu"
            else max(self.inference_chunk, ACCELERATOR_CHUNK)
        )
        return torch.cat(
            [
                self(rgbh[i : i + step], pick[i : i + step], place[i : i + step], yaws[i : i + step])
                for i in range(0, b, step)
            ]
        )

    @torch.no_grad()
    def predict_rgbh(
        self, rgbh: torch.Tensor, pick_pixels: ArrayLike, place_pixels: ArrayLike, yaws: ArrayLike
    ) -> torch.Tensor:
        """Inference on normalised RGB-H, clamped to physical ranges (for feeding back to the GCTN)."""
        return clamp_rgbh(self._predict_chunked(rgbh, pick_pixels, place_pixels, yaws))

    @torch.no_grad()
    def predict(
        self,
        color: ArrayLike,
        height: ArrayLike,
        pick_pixels: ArrayLike,
        place_pixels: ArrayLike,
        yaws: ArrayLike,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Physical-unit inference: colour (B, H, W, 3) float in 0..255, height (B, H, W) in 0..0.28 m.

        Inputs: ``color`` (B, H, W, 3) uint8/float 0..255, ``height`` (B, H, W) metres, pixels (B, 2)
        int (row, col), ``yaws`` (B,) place yaw change in radians (world yaw, geometry's convention).
        """
        device = next(self.parameters()).device
        rgbh = to_rgbh(color, height).to(device)
        color_out, height_out = from_rgbh(self._predict_chunked(rgbh, pick_pixels, place_pixels, yaws))
        return color_out.clamp(0.0, 255.0), height_out.clamp(0.0, MAX_HEIGHT)


class VisualForesight(ImagePredictor, nn.Module):
    """ResNet36_4s-like FCN 9 -> 4 channels predicting the next normalised RGB-H image."""

    checkpoint_kind = "vf"

    def __init__(self, preset: ModelPreset, seed: int = 0) -> None:
        """Build the network; weights are drawn from a generator seeded with ``seed``."""
        super().__init__()
        self.preset = preset
        generator = torch.Generator().manual_seed(seed)
        self.blend = preset.vf_head == "blend"
        outputs = RGBH_CHANNELS + (len(BLEND_SOURCES) if self.blend else 0)
        self.fcn = resnet36_4s(ACTION_CHANNELS, outputs, preset.vf_width, preset.channels_last, generator)
        self.window = preset.vf_window
        self.pad = preset.vf_pad
        self.residual = preset.vf_residual

    def config(self) -> dict:
        """Everything needed to rebuild this model (stored in checkpoints)."""
        return {"preset": self.preset.as_dict()}

    def forward(
        self, rgbh: torch.Tensor, pick_pixels: torch.Tensor, place_pixels: torch.Tensor, yaws: torch.Tensor
    ) -> torch.Tensor:
        """Predicted next normalised RGB-H (B, 4, H, W), not clamped."""
        b, shape = rgbh.shape[0], rgbh.shape[-2:]
        pick = as_pixels(pick_pixels, b, shape).to(rgbh.device)
        place = as_pixels(place_pixels, b, shape).to(rgbh.device)
        yaws = torch.as_tensor(yaws, dtype=torch.float32).reshape(-1).expand(b)
        enc = encode_action(rgbh, pick, place, yaws, self.window)
        p = self.pad
        y = self.fcn(F.pad(enc, (p, p, p, p)) if p else enc)
        if p:
            y = y[:, :, p:-p, p:-p]
        y = y.contiguous()
        if self.blend:
            return blend_output(rgbh, enc, y, place, self.window)
        if self.preset.vf_head == "local":
            return local_output(rgbh, rgbh + y if self.residual else y, pick, place, self.window)
        return rgbh + y if self.residual else y

    def loss(
        self,
        rgbh: torch.Tensor,
        pick_pixels: torch.Tensor,
        place_pixels: torch.Tensor,
        yaws: torch.Tensor,
        target: torch.Tensor,
        pixel_weights: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Training loss (:func:`vf_loss`) of the prediction against the next normalised RGB-H."""
        return vf_loss(self(rgbh, pick_pixels, place_pixels, yaws), target, pixel_weights)

    def rollout_loss(
        self,
        rgbh: torch.Tensor,
        picks: torch.Tensor,
        places: torch.Tensor,
        yaws: torch.Tensor,
        targets: list[torch.Tensor],
        pixel_weights: list[torch.Tensor] | None = None,
    ) -> torch.Tensor:
        """The multi-step (rollout) loss: the mean of :func:`vf_loss` over H steps, each step predicted
        from the model's own clamped prediction of the step before (gradients flow through the whole
        rollout), as the planner feeds it. ``picks`` / ``places`` (B, H, 2), ``yaws`` (B, H),
        ``targets`` H normalised RGB-H images (B, 4, h, w), ``pixel_weights`` H (B, h, w) or None.
        H = 1 is :meth:`loss`."""
        state, total = rgbh, rgbh.new_zeros(())
        for k, target in enumerate(targets):
            predicted = self(state, picks[:, k], places[:, k], yaws[:, k])
            total = total + vf_loss(predicted, target, None if pixel_weights is None else pixel_weights[k])
            state = clamp_rgbh(predicted)
        return total / len(targets)
