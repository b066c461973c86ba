"""Latent-dynamics baseline: encode the image to a small latent, step the latent with the action, decode.

The paper compares its visual foresight (VF) with a "Latent-Dynamics" model but does not give its
architecture; this one is ours (docs/models.md, "Latent-dynamics baseline"; docs/deviations.md):

* **Encoder**: normalised RGB-H (B, 4, 160, 160) -> a *spatial* latent (B, C, 10, 10): a 3x3 stem, then
  four levels of (3x3 stride-2 conv, 3x3 conv), each halving the side, and a 1x1 projection to C
  channels. One cell summarises 16 x 16 pixels (5 cm, about one block). A spatial grid keeps *where*
  things are; a single vector would have to learn positions from scratch and, at these sizes, blurs the
  whole scene into a mean image.
* **Transition**: z' = z + T(z, a). The action enters as a **vector** (pick row and col, place row and
  col, cos and sin of the place yaw change), tiled over the grid with each cell's own row and col
  (CoordConv), :func:`encode_latent_action`; T is a 1x1 conv and four residual 3x3 blocks (dilations 1, 2,
  4, 1: a 17-cell receptive field, wider than the grid, so a block can be carried anywhere) and a 1x1
  back to C. The VF's pick and place masks are *not* used: the place mask hands the network the moved
  block's pixels at full resolution, the very thing a latent model has to carry through its bottleneck.
* **Decoder**: latent -> 3x3 conv, four levels of (bilinear x2 upsampling, two 3x3 convs), a 3x3 conv to
  the 4 RGB-H channels without activation: the next image directly, like the VF. No skip connections
  (they would bypass the latent).

Convolutions have biases, He-uniform weights before a ReLU and Glorot-uniform ones elsewhere, drawn from
the model's seed (T's last layer starts at zero: z' = z); ReLUs between them, no normalisation layers
(as the VF). Loss (``LatentDynamics.losses``): the VF's L1 (:func:`tvf.models.vf.vf_loss`) of the
decoded next latent against the next image, plus ``recon_weight`` times the squared error of the decoded
current latent against the current image (an auto-encoder term) and ``latent_weight`` times the squared
distance of the next latent to the encoding of the real next image (a latent-prediction term).

Prediction is image to image (:meth:`predict_rgbh`, shared with the VF), so multi-step rollouts and the
planner re-encode each decoded image, as they feed the VF its own outputs.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn
from torch.nn import functional as F

from tvf.models.backbone import scaled
from tvf.models.images import RGBH_CHANNELS, as_pixels
from tvf.models.presets import LatentPreset, ModelPreset, PresetError, get_latent_preset
from tvf.models.vf import HEIGHT_WEIGHT, ImagePredictor, vf_loss

STRIDE = 16
"""Pixels per latent cell along each side (four stride-2 levels)."""
ENCODER_WIDTHS = (32, 64, 128, 128)
"""Full-width channels of the encoder levels (sides 80, 40, 20, 10); the decoder mirrors them."""
TRANSITION_WIDTH = 128
TRANSITION_DILATIONS = (1, 2, 4, 1)
ACTION_FEATURES = 8
"""Tiled action: pick (row, col), place (row, col), cos yaw, sin yaw, then the cell's (row, col)."""


def _conv(c_in: int, c_out: int, kernel: int, generator: torch.Generator, stride: int = 1,
          dilation: int = 1, relu: bool = True) -> nn.Conv2d:  # fmt: skip
    """Conv with bias, 'same' padding (at stride 1) and zero bias; He-uniform weights from ``generator``
    when a ReLU follows (``relu``), Glorot-uniform otherwise. (Glorot before every ReLU, as the VF,
    shrinks the signal of this plain, 30-layer stack about 100-fold: the untrained output was 0.013
    in normalised units, and an auto-encoder of one scene barely moved in 60 steps.)"""
    conv = nn.Conv2d(c_in, c_out, kernel, stride, padding=dilation * (kernel // 2), dilation=dilation)
    if relu:
        nn.init.kaiming_uniform_(conv.weight, nonlinearity="relu", generator=generator)
    else:
        nn.init.xavier_uniform_(conv.weight, generator=generator)
    nn.init.zeros_(conv.bias)
    return conv


def rgbh_mse(predicted: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Squared error on normalised RGB-H, height weighted x5 as :func:`vf_loss`: mean over pixels of
    (dR^2 + dG^2 + dB^2 + 5 dH^2) / 4."""
    weights = torch.tensor([1.0, 1.0, 1.0, HEIGHT_WEIGHT], device=predicted.device, dtype=predicted.dtype)
    return (((predicted - target) ** 2) * weights.view(1, 4, 1, 1)).sum(dim=1).mean() / RGBH_CHANNELS


def _unit(pixels: torch.Tensor, size: int) -> torch.Tensor:
    """Pixel coordinates 0 .. size-1 -> -1 .. 1."""
    return pixels.to(torch.float32) * (2.0 / (size - 1)) - 1.0


def encode_latent_action(
    pick: torch.Tensor, place: torch.Tensor, yaws: torch.Tensor, grid: int, image_size: int
) -> torch.Tensor:
    """The action as a vector tiled over the latent grid, with each cell's position: (B, 8, grid, grid).

    Channels: pick row, pick col, place row, place col (pixels scaled to -1 .. 1), cos and sin of the
    place yaw change, then the cell centre's row and col on the same scale.
    """
    b = pick.shape[0]
    yaws = torch.as_tensor(yaws, dtype=torch.float32, device=pick.device).reshape(-1).expand(b)
    vector = torch.cat([_unit(pick, image_size), _unit(place, image_size),
                        torch.cos(yaws)[:, None], torch.sin(yaws)[:, None]], dim=1)  # fmt: skip
    centres = _unit((torch.arange(grid, device=pick.device) + 0.5) * (image_size / grid) - 0.5, image_size)
    rows = centres.view(1, 1, grid, 1).expand(b, 1, grid, grid)
    cols = centres.view(1, 1, 1, grid).expand(b, 1, grid, grid)
    return torch.cat([vector[:, :, None, None].expand(b, 6, grid, grid), rows, cols], dim=1)


class Encoder(nn.Module):
    """RGB-H (B, 4, S, S) -> latent (B, C, S/16, S/16)."""

    def __init__(self, widths: tuple[int, ...], channels: int, generator: torch.Generator) -> None:
        super().__init__()
        layers: list[nn.Module] = [_conv(RGBH_CHANNELS, widths[0], 3, generator), nn.ReLU(inplace=True)]
        c = widths[0]
        for w in widths:
            layers += [_conv(c, w, 3, generator, stride=2), nn.ReLU(inplace=True),
                       _conv(w, w, 3, generator), nn.ReLU(inplace=True)]  # fmt: skip
            c = w
        layers.append(_conv(c, channels, 1, generator, relu=False))
        self.net = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


class ResidualBlock(nn.Module):
    """x + conv3x3(relu(conv3x3_dilated(x))), then ReLU."""

    def __init__(self, width: int, dilation: int, generator: torch.Generator) -> None:
        super().__init__()
        self.first = _conv(width, width, 3, generator, dilation=dilation)
        self.second = _conv(width, width, 3, generator, relu=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(x + self.second(F.relu(self.first(x))))


class Transition(nn.Module):
    """(latent (B, C, g, g), tiled action (B, 8, g, g)) -> the latent's change (B, C, g, g)."""

    def __init__(self, channels: int, width: int, generator: torch.Generator) -> None:
        super().__init__()
        self.inp = _conv(channels + ACTION_FEATURES, width, 1, generator)
        self.blocks = nn.Sequential(*(ResidualBlock(width, d, generator) for d in TRANSITION_DILATIONS))
        self.out = _conv(width, channels, 1, generator, relu=False)
        nn.init.zeros_(self.out.weight)  # z' = z at the start: the next image is first the reconstruction

    def forward(self, z: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return self.out(self.blocks(F.relu(self.inp(torch.cat([z, action], dim=1)))))


class Decoder(nn.Module):
    """Latent (B, C, g, g) -> RGB-H (B, 4, 16 g, 16 g), unclamped, no final activation."""

    def __init__(self, widths: tuple[int, ...], channels: int, generator: torch.Generator) -> None:
        super().__init__()
        c = widths[0]
        self.inp = _conv(channels, c, 3, generator)
        self.levels = nn.ModuleList()
        for w in widths:
            self.levels.append(nn.Sequential(_conv(c, w, 3, generator), nn.ReLU(inplace=True),
                                             _conv(w, w, 3, generator), nn.ReLU(inplace=True)))  # fmt: skip
            c = w
        self.out = _conv(c, RGBH_CHANNELS, 3, generator, relu=False)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        x = F.relu(self.inp(z))
        for level in self.levels:
            x = level(F.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False))
        return self.out(x)


class LatentDynamics(ImagePredictor, nn.Module):
    """Encoder -> action-conditioned latent transition -> decoder, predicting the next normalised RGB-H.

    Called like :class:`tvf.models.vf.VisualForesight` (``model(rgbh, pick, place, yaws)``,
    :meth:`predict_rgbh`, :meth:`predict`), so `tvf eval-vf` and the planner take either.
    """

    checkpoint_kind = "latent"

    def __init__(self, preset: ModelPreset, seed: int = 0, latent: LatentPreset | None = None) -> None:
        """Build the network (sizes: ``latent``, default the preset's :data:`LATENT_PRESETS` entry);
        weights are drawn from a generator seeded with ``seed``."""
        super().__init__()
        if preset.image_size % STRIDE:
            raise PresetError(
                f"the latent model needs an image_size divisible by {STRIDE}, not {preset.image_size}"
            )
        self.preset = preset
        self.latent = latent or get_latent_preset(preset.name)
        self.window = preset.vf_window  # the paste baseline's window in `tvf eval-vf`
        self.grid = preset.image_size // STRIDE
        generator = torch.Generator().manual_seed(seed)
        widths = tuple(scaled(c, self.latent.width) for c in ENCODER_WIDTHS)
        c = self.latent.channels
        self.encoder = Encoder(widths, c, generator)
        self.transition = Transition(c, scaled(TRANSITION_WIDTH, self.latent.width), generator)
        self.decoder = Decoder(widths[::-1], c, generator)
        if preset.channels_last:
            self.to(memory_format=torch.channels_last)

    @classmethod
    def from_config(cls, preset: ModelPreset, config: dict[str, Any]) -> LatentDynamics:
        """Rebuild from a checkpoint's config (:meth:`config`)."""
        return cls(preset, latent=LatentPreset.from_dict(config["latent"]))

    def config(self) -> dict:
        """Everything needed to rebuild this model (stored in checkpoints)."""
        return {"preset": self.preset.as_dict(), "latent": self.latent.as_dict()}

    def _format(self, x: torch.Tensor) -> torch.Tensor:
        return x.contiguous(memory_format=torch.channels_last) if self.preset.channels_last else x

    def encode(self, rgbh: torch.Tensor) -> torch.Tensor:
        """Normalised RGB-H (B, 4, H, W) -> latent (B, C, H/16, W/16)."""
        return self.encoder(self._format(rgbh))

    def step(
        self, z: torch.Tensor, pick: torch.Tensor, place: torch.Tensor, yaws: torch.Tensor
    ) -> torch.Tensor:
        """The next latent: z + T(z, action); ``pick``/``place`` (B, 2) int64 pixels, ``yaws`` (B,)."""
        action = encode_latent_action(pick, place, yaws, self.grid, self.preset.image_size).to(z.dtype)
        return z + self.transition(z, self._format(action))

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        """Latent -> normalised RGB-H (B, 4, H, W), unclamped."""
        return self.decoder(z).contiguous()

    def _inputs(self, rgbh, pick_pixels, place_pixels, yaws) -> tuple[torch.Tensor, ...]:
        b, shape = rgbh.shape[0], rgbh.shape[-2:]
        pick = as_pixels(pick_pixels, b, shape).to(rgbh.device)
        place = as_pixels(place_pixels, b, shape).to(rgbh.device)
        yaws = torch.as_tensor(yaws, dtype=torch.float32).reshape(-1).expand(b).to(rgbh.device)
        return pick, place, yaws

    def forward(
        self, rgbh: torch.Tensor, pick_pixels: torch.Tensor, place_pixels: torch.Tensor, yaws: torch.Tensor
    ) -> torch.Tensor:
        """Predicted next normalised RGB-H (B, 4, H, W), not clamped."""
        return self.decode(self.step(self.encode(rgbh), *self._inputs(rgbh, pick_pixels, place_pixels, yaws)))

    def losses(
        self,
        rgbh: torch.Tensor,
        pick_pixels: torch.Tensor,
        place_pixels: torch.Tensor,
        yaws: torch.Tensor,
        target: torch.Tensor,
        pixel_weights: torch.Tensor | None = None,
    ) -> dict[str, torch.Tensor]:
        """{"next", "recon", "latent", "total"}: the terms of the training loss and their weighted sum.

        * "next": :func:`vf_loss` (the VF's L1) of the decoded next latent against ``target``; the
          ``pixel_weights`` (changed-pixel weights) apply to it alone;
        * "recon": :func:`rgbh_mse` of the decoded current latent against ``rgbh``;
        * "latent": mean squared difference between the next latent and the encoding of ``target``,
          which is held fixed (no gradient through the target's encoding);
        * "total": next + ``recon_weight`` * recon + ``latent_weight`` * latent.

        A term of weight 0 is not computed (zero).
        """
        z = self.encode(rgbh)
        z_next = self.step(z, *self._inputs(rgbh, pick_pixels, place_pixels, yaws))
        w_recon, w_latent = self.latent.recon_weight, self.latent.latent_weight
        b = rgbh.shape[0]
        images = self.decode(torch.cat([z_next, z]) if w_recon else z_next)  # one decoder call
        nxt = vf_loss(images[:b], target, pixel_weights)
        zero = torch.zeros_like(nxt)
        recon = rgbh_mse(images[b:], rgbh) if w_recon else zero
        if w_latent:
            with torch.no_grad():
                z_true = self.encode(target)
            latent = (z_next - z_true).pow(2).mean()
        else:
            latent = zero
        total = nxt + w_recon * recon + w_latent * latent
        return {"next": nxt, "recon": recon, "latent": latent, "total": total}

    def loss(
        self,
        rgbh: torch.Tensor,
        pick_pixels: torch.Tensor,
        place_pixels: torch.Tensor,
        yaws: torch.Tensor,
        target: torch.Tensor,
        pixel_weights: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """The training loss, :meth:`losses`' "total" (the VF's signature)."""
        return self.losses(rgbh, pick_pixels, place_pixels, yaws, target, pixel_weights)["total"]
