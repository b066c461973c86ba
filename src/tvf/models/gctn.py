"""Goal-Conditioned Transporter Network (GCTN): pick attention and goal-conditioned transport.

Inputs are normalised RGB-H tensors ``(B, 4, H, W)`` (see :mod:`tvf.models.images`), 4 channels per
image (RGB + height, not the reference's RGBHHH). Pixels are ``(row, col)`` int64 ``(B, 2)``.

Rotation convention (see :mod:`tvf.geometry`): place logit ``[b, r, u, v]`` scores "pick at the pick
pixel, turn the object by world yaw ``transport.yaws[r]`` and put it at pixel ``(u, v)``"; that yaw is
``r * 2*pi / 36`` for the 36-channel presets, and one period of the object's symmetry, centred on no
turn, when ``preset.symmetry`` > 1 (:func:`channel_bins`). To score it, the
query features around the pick are turned by **+yaw** (content motion ``p' = R(yaw)(p - pick) + pick``
in (col, row), i.e. :func:`tvf.geometry.se2_output_to_input` with ``+yaw``), so the rotated crop shows
the object as it will look after the place; the crop is then cross-correlated with the goal-fused
key map, whose window centred at ``(u, v)`` shows what the goal wants there.
"""

from __future__ import annotations

import functools
import math

import torch
from torch import nn
from torch.nn import functional as F

from tvf.geometry import se2_output_to_input, warp_images
from tvf.models.backbone import resnet43_8s
from tvf.models.images import RGBH_CHANNELS, as_pixels
from tvf.models.presets import ModelPreset

# --------------------------------------------------------------------------------------------
# Cross-correlation of per-sample, per-rotation kernels with per-sample key maps.


def cross_correlate_conv(keys: torch.Tensor, kernels: torch.Tensor) -> torch.Tensor:
    """``out[b, r, u, v] = sum_{c,i,j} keys[b, c, u+i, v+j] * kernels[b, r, c, i, j]`` ("valid").

    ``keys`` (B, C, P, P), ``kernels`` (B, R, C, k, k) -> (B, R, P-k+1, P-k+1); one grouped conv2d.
    """
    b, c, ph, pw = keys.shape
    r, k = kernels.shape[1], kernels.shape[-1]
    out = F.conv2d(keys.reshape(1, b * c, ph, pw), kernels.reshape(b * r, c, k, k), groups=b)
    return out.view(b, r, ph - k + 1, pw - k + 1)


def _irfft2_top_left(spectrum: torch.Tensor, size: tuple[int, int], rows: int, cols: int) -> torch.Tensor:
    """``irfft2(spectrum, s=size)[..., :rows, :cols]``, skipping the rows that are not needed."""
    return torch.fft.irfft(torch.fft.ifft(spectrum, dim=-2)[..., :rows, :], n=size[1], dim=-1)[..., :cols]


@functools.lru_cache(maxsize=8)
def _inverse_dft_rows(n: int, rows: int) -> torch.Tensor:
    """(rows, n) complex matrix: the first ``rows`` outputs of a length-n inverse DFT."""
    freq = torch.arange(n, dtype=torch.float64)
    out = torch.arange(rows, dtype=torch.float64)
    return (torch.exp(2j * math.pi * torch.outer(out, freq) / n) / n).to(torch.complex64)


@functools.lru_cache(maxsize=8)
def _inverse_rdft_cols(n: int, cols: int) -> torch.Tensor:
    """(2 * (n//2+1), cols) real matrix: the first ``cols`` outputs of ``irfft(., n)`` on (re, im) pairs."""
    m = n // 2 + 1
    freq = torch.arange(m, dtype=torch.float64)
    out = torch.arange(cols, dtype=torch.float64)
    weight = torch.full((m,), 2.0, dtype=torch.float64)
    weight[0] = 1.0
    if n % 2 == 0:
        weight[-1] = 1.0
    angle = 2 * math.pi * torch.outer(freq, out) / n
    pairs = torch.stack([weight[:, None] * torch.cos(angle), -weight[:, None] * torch.sin(angle)], dim=1)
    return (pairs / n).reshape(2 * m, cols).to(torch.float32)


def _pruned_irfft2(spectrum: torch.Tensor, size: tuple[int, int], rows: int, cols: int) -> torch.Tensor:
    """``irfft2(spectrum, s=size)[..., :rows, :cols]`` as two matmuls (cheap when rows, cols << size)."""
    device = spectrum.device
    top = _inverse_dft_rows(size[0], rows).to(device) @ spectrum  # (..., rows, size[1]//2+1)
    return torch.view_as_real(top).flatten(-2) @ _inverse_rdft_cols(size[1], cols).to(device)


class _FFTCrossCorrelation(torch.autograd.Function):
    """FFT cross-correlation with a hand-written backward (autograd's rfft2 backward is a full c2c FFT)."""

    @staticmethod
    def forward(ctx, keys: torch.Tensor, kernels: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        size = (keys.shape[-2], keys.shape[-1])
        k = kernels.shape[-1]
        key_f = torch.fft.rfft2(keys, s=size)  # (B, C, P, P//2+1)
        kernel_f = torch.fft.rfft2(kernels, s=size)  # (B, R, C, P, P//2+1), zero-padded at the end
        product = key_f[:, 0, None] * kernel_f[:, :, 0].conj()  # sum over the few channels, no big copies
        for c in range(1, keys.shape[1]):
            product += key_f[:, c, None] * kernel_f[:, :, c].conj()
        ctx.save_for_backward(key_f, kernel_f)
        ctx.geometry = (size, k)
        return _irfft2_top_left(product, size, size[0] - k + 1, size[1] - k + 1)

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> tuple[torch.Tensor | None, torch.Tensor | None]:  # type: ignore[override]
        key_f, kernel_f = ctx.saved_tensors
        size, k = ctx.geometry
        grad_f = torch.fft.rfft2(grad, s=size)  # (B, R, P, P//2+1)
        grad_keys = grad_kernels = None
        if ctx.needs_input_grad[0]:  # d/dA_c = sum_r g_r (*) K_rc  (a convolution)
            channels = [(grad_f * kernel_f[:, :, c]).sum(dim=1) for c in range(key_f.shape[1])]
            grad_keys = torch.fft.irfft2(torch.stack(channels, dim=1), s=size)
        if ctx.needs_input_grad[1]:  # d/dK_rc = A_c (x) g_r  (a correlation), only the k x k corner
            product = key_f.unsqueeze(1) * grad_f.conj().unsqueeze(2)  # (B, R, C, P, P//2+1)
            grad_kernels = _pruned_irfft2(product, size, k, k)
        return grad_keys, grad_kernels


def cross_correlate_fft(keys: torch.Tensor, kernels: torch.Tensor) -> torch.Tensor:
    """Same as :func:`cross_correlate_conv`, via real FFTs of the key size (float32).

    Circular correlation of size P is exact for the P-k+1 "valid" offsets (no wrap-around).
    """
    return _FFTCrossCorrelation.apply(keys.float().contiguous(), kernels.float().contiguous())


CORRELATIONS = {"fft": cross_correlate_fft, "conv": cross_correlate_conv}


# --------------------------------------------------------------------------------------------
# Rotated crops around the pick.


def rotation_window(crop: int) -> int:
    """Even side of the square window that still holds a ``crop`` square after any rotation."""
    return 2 * math.ceil(crop / math.sqrt(2)) + 4


def rotated_crops(
    features: torch.Tensor,
    pick: torch.Tensor,
    pad: int,
    crop: int,
    yaws: torch.Tensor,
    mode: str = "bilinear",
) -> torch.Tensor:
    """Cut ``crop`` x ``crop`` kernels around each pick pixel, content turned by each yaw about the pick.

    ``features`` (B, C, P, P) are maps of the image padded by ``pad``; ``pick`` (B, 2) are (row, col)
    pixels of the *unpadded* image; ``yaws`` (R,) world yaws. Returns (B, R, C, crop, crop) whose index
    ``crop // 2`` (row and col) is the pick pixel. Uses one :func:`tvf.geometry.warp_images` call.
    """
    b, c = features.shape[:2]
    r = yaws.shape[0]
    side = rotation_window(crop)
    half = side // 2
    extra = half - pad  # more zero padding so every window lies inside the map
    if extra > 0:
        features = F.pad(features, (extra, extra, extra, extra))
    start = pick + (pad + max(extra, 0) - half)  # window top-left in the (re)padded map
    offsets = torch.arange(side, device=features.device)
    rows = (start[:, 0:1] + offsets)[:, :, None]  # (B, S, 1)
    cols = (start[:, 1:2] + offsets)[:, None, :]  # (B, 1, S)
    batch = torch.arange(b, device=features.device)[:, None, None]
    windows = features[batch, :, rows, cols].permute(0, 3, 1, 2)  # (B, C, S, S), pick at (half, half)
    centre = torch.full((r, 2), float(half))
    out_to_in = se2_output_to_input(yaws.float().cpu(), centre).repeat(b, 1, 1)  # index b * R + r
    turned = warp_images(windows.repeat_interleave(r, dim=0), out_to_in, mode=mode)
    lo = half - crop // 2
    return turned[:, :, lo : lo + crop, lo : lo + crop].reshape(b, r, c, crop, crop)


def rotation_yaws(n_rotations: int, symmetry: int = 1) -> torch.Tensor:
    """Yaw of each place-map channel: ``channel_bins(n_rotations, symmetry) * 2*pi / n_rotations``."""
    return channel_bins(n_rotations, symmetry).float() * (2 * math.pi / n_rotations)


def channel_bins(n_rotations: int, symmetry: int = 1) -> torch.Tensor:
    """The rotation bin (of ``n_rotations`` per turn) that each place-map channel scores.

    With ``symmetry`` s the map has P = n_rotations / s channels: the bins of one period centred on no
    turn, channel c holding the signed turn ``((c + P//2) mod P) - P//2`` bins. Every bin b is then the
    same turn (for the object) as channel ``b mod P``, which is the training label. With s = 1 the
    channel is the bin itself; with 36 bins and s = 4: channels 0..8 are turns of 0, 10, ..., 40, -40,
    ..., -10 degrees.
    """
    period = n_rotations // symmetry
    signed = (torch.arange(period) + period // 2) % period - period // 2
    return signed % n_rotations


# --------------------------------------------------------------------------------------------
# Networks.


INFERENCE_CHUNK = 2
"""Largest batch run at once without gradients. Per-state cost on the 2-core CPU rises with the batch
(the FFT correlation is memory-bound). With one thread per process and another process beside it
(the evaluation set-up), lite place_map took 122 / 81 / 108 / 186 ms per state at chunks 1 / 2 / 3 / 8."""
ACCELERATOR_CHUNK = 32
"""Largest batch run at once without gradients on a GPU, where large batches are the point (a level of
several environments' trees, `tvf eval --envs-per-worker`); not tuned yet: no GPU was lent so far."""


def inference_chunk(device: torch.device) -> int:
    """The no-gradient chunk on ``device``: :data:`INFERENCE_CHUNK` on the CPU, else
    :data:`ACCELERATOR_CHUNK`."""
    return INFERENCE_CHUNK if device.type == "cpu" else ACCELERATOR_CHUNK


def _require(goal: torch.Tensor | None) -> torch.Tensor:
    if goal is None:
        raise ValueError("pass goal or goal_features")
    return goal


def _match_batch(goal: torch.Tensor, batch: int) -> torch.Tensor:
    """Broadcast a batch-1 goal tensor to ``batch`` (one goal shared by many states)."""
    if goal.shape[0] == batch:
        return goal
    if goal.shape[0] == 1:
        return goal.expand(batch, *goal.shape[1:])
    raise ValueError(f"goal batch {goal.shape[0]} does not match state batch {batch}")


class Attention(nn.Module):
    """Pick attention: one FCN on current || goal RGB-H (8 channels) -> 1 logit per pixel."""

    def __init__(self, preset: ModelPreset, generator: torch.Generator | None = None) -> None:
        super().__init__()
        self.fcn = resnet43_8s(2 * RGBH_CHANNELS, 1, preset.attention_width, preset.channels_last, generator,
                               c4=preset.gctn_kernels == "c4")  # fmt: skip

    def forward(self, current: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """(B, 4, H, W) x2 -> pick logits (B, H, W)."""
        goal = _match_batch(goal, current.shape[0])
        return self.fcn(torch.cat([current, goal], dim=1))[:, 0].contiguous()


class Transport(nn.Module):
    """Goal-conditioned transport: key, query and goal FCNs, product fusion, rotated-crop correlation."""

    def __init__(self, preset: ModelPreset, generator: torch.Generator | None = None) -> None:
        super().__init__()
        width, ch, cl = preset.transport_width, preset.transport_channels, preset.channels_last
        c4 = preset.gctn_kernels == "c4"
        self.key = resnet43_8s(RGBH_CHANNELS, ch, width, cl, generator, c4)
        self.query = resnet43_8s(RGBH_CHANNELS, ch, width, cl, generator, c4)
        self.goal = resnet43_8s(RGBH_CHANNELS, ch, width, cl, generator, c4)
        self.crop = preset.crop
        self.pad = preset.crop // 2
        self.image_size = preset.image_size
        self.correlate = CORRELATIONS[preset.correlation]
        self.pad_features = preset.pad_features
        self.register_buffer("yaws", rotation_yaws(preset.n_rotations, preset.symmetry), persistent=False)

    def _padded(self, images: torch.Tensor) -> torch.Tensor:
        p = self.pad
        return F.pad(images, (p, p, p, p))

    def _features(self, net: nn.Module, images: torch.Tensor) -> torch.Tensor:
        """``net``'s feature maps of the images padded by ``crop / 2`` (B, C, P, P)."""
        if self.pad_features:
            return self._padded(net(images))
        return net(self._padded(images))

    def goal_features(self, goal: torch.Tensor) -> torch.Tensor:
        """Goal feature maps (B or 1, C, P, P); cache them when the goal is reused."""
        return self._features(self.goal, goal)

    def forward(
        self,
        current: torch.Tensor,
        goal: torch.Tensor | None,
        pick: torch.Tensor,
        goal_features: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Place logits (B, R, H, W) for picks ``pick`` (B, 2); pass ``goal`` or ``goal_features``.

        R = ``preset.place_rotations``; channel r turns the object by ``self.yaws[r]``.
        """
        return self.place_maps(current, goal, pick[:, None], goal_features)[:, 0]

    def place_maps(
        self,
        current: torch.Tensor,
        goal: torch.Tensor | None,
        picks: torch.Tensor,
        goal_features: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Place logits (B, P, R, H, W) at P picks per state (``picks`` (B, P, 2)).

        The key and query FCNs run once per state; only the rotated crops and the correlation are
        repeated per pick, so P picks cost much less than P calls of :meth:`forward`.
        """
        if goal_features is None:
            goal_features = self.goal_features(_require(goal))
        b, p = picks.shape[:2]
        goal_features = _match_batch(goal_features, b)
        keys = goal_features * self._features(self.key, current)
        queries = goal_features * self._features(self.query, current)
        if p > 1:
            queries = queries.repeat_interleave(p, dim=0)  # row b * P + j: state b at its j-th pick
        kernels = rotated_crops(queries, picks.reshape(b * p, 2), self.pad, self.crop, self.yaws)
        r = kernels.shape[1]
        kernels = kernels.reshape(b, p * r, *kernels.shape[2:])
        logits = self.correlate(keys.contiguous(), kernels)
        n = self.image_size
        return logits[..., :n, :n].reshape(b, p, r, n, n) / float(self.crop**2)


def _flat_index(pixels: torch.Tensor, width: int) -> torch.Tensor:
    return pixels[:, 0] * width + pixels[:, 1]


def argmax_pixels(logits: torch.Tensor) -> torch.Tensor:
    """(B, H, W) maps -> (B, 2) int64 (row, col) of each map's maximum (the first one on ties)."""
    b, h, w = logits.shape
    return torch.stack(_unravel(logits.reshape(b, -1).argmax(dim=1), (h, w)), dim=1)


def argmax_places(place_logits: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(B, R, H, W) place logits -> the best (row, col) (B, 2) and rotation bin (B,) of each state."""
    b = place_logits.shape[0]
    rot, row, col = _unravel(place_logits.reshape(b, -1).argmax(dim=1), tuple(place_logits.shape[1:]))
    return torch.stack([row, col], dim=1), rot


def _unravel(index: torch.Tensor, shape: tuple[int, ...]) -> list[torch.Tensor]:
    out = []
    for size in reversed(shape):
        out.append(index % size)
        index = torch.div(index, size, rounding_mode="floor")
    return out[::-1]


def gctn_loss(
    pick_logits: torch.Tensor,
    place_logits: torch.Tensor,
    pick_pixels: torch.Tensor,
    place_pixels: torch.Tensor,
    rot_bins: torch.Tensor,
) -> dict[str, torch.Tensor]:
    """Softmax cross-entropies: pick over H*W pixels, place over R*H*W; returns pick, place, total.

    ``rot_bins`` are bins of a full turn; bin b is labelled on channel ``b mod R`` (see
    :func:`channel_bins`), the same turn when the map covers one symmetry period.
    """
    b, h, w = pick_logits.shape
    r = place_logits.shape[1]
    pick_target = _flat_index(pick_pixels, w)
    place_target = (rot_bins.to(torch.int64) % r) * (h * w) + _flat_index(place_pixels, w)
    pick = F.cross_entropy(pick_logits.reshape(b, h * w), pick_target)
    place = F.cross_entropy(place_logits.reshape(b, r * h * w), place_target)
    return {"pick": pick, "place": place, "total": pick + place}


class GCTN(nn.Module):
    """Attention (pick) + goal-conditioned transport (place) for 160 x 160 RGB-H images."""

    checkpoint_kind = "gctn"

    def __init__(self, preset: ModelPreset, seed: int = 0) -> None:
        """Build the networks; weights are drawn from a generator seeded with ``seed``."""
        super().__init__()
        self.preset = preset
        generator = torch.Generator().manual_seed(seed)
        self.attention = Attention(preset, generator)
        self.transport = Transport(preset, generator)
        bins = channel_bins(preset.n_rotations, preset.symmetry)
        self.register_buffer("channel_bins", bins, persistent=False)

    def config(self) -> dict:
        """Everything needed to rebuild this model (stored in checkpoints)."""
        return {"preset": self.preset.as_dict()}

    def pick_logits(self, current: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """Pick logits (B, H, W); without gradients, large batches run in chunks."""
        b, chunk = current.shape[0], inference_chunk(current.device)
        if torch.is_grad_enabled() or b <= chunk:
            return self.attention(current, goal)
        goal = _match_batch(goal, b)
        return torch.cat(
            [self.attention(current[lo : lo + chunk], goal[lo : lo + chunk]) for lo in range(0, b, chunk)]
        )

    def goal_features(self, goal: torch.Tensor) -> torch.Tensor:
        """The transport's goal feature maps; compute them once when one goal serves many states."""
        return self.transport.goal_features(goal)

    def pick_pixels(self, current: torch.Tensor, picks: torch.Tensor) -> torch.Tensor:
        """Where the picks (B, P, 2) chosen from :meth:`pick_logits` of ``current`` go: unchanged here
        (a wrapper may move them, :mod:`tvf.models.pick_centre`)."""
        return picks

    def rotation_bins(self, channels: torch.Tensor) -> torch.Tensor:
        """The rotation bin of a full turn (of ``preset.n_rotations``) of each place-map channel."""
        index = torch.as_tensor(channels, dtype=torch.int64, device=self.channel_bins.device)
        return self.channel_bins[index]

    def place_map(
        self,
        current: torch.Tensor,
        goal: torch.Tensor | None,
        pick_pixels: torch.Tensor,
        goal_features: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Place logits (B, R, H, W) for the given picks; a batch-1 goal is shared by all states.

        Without gradients, batches larger than :func:`inference_chunk` run in chunks (faster on CPU).
        """
        return one_pick_place_map(self, current, goal, pick_pixels, goal_features)

    def place_maps(
        self,
        current: torch.Tensor,
        goal: torch.Tensor | None,
        picks: torch.Tensor,
        goal_features: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Place logits (B, P, R, H, W) at P picks per state (``picks`` (B, P, 2) int pixels).

        Each state's key and query maps are computed once for all its picks. Chunked like
        :meth:`place_map` (chunks of :func:`inference_chunk` states).
        """
        b = current.shape[0]
        picks = torch.as_tensor(picks)
        if picks.dim() != 3 or picks.shape[0] != b:
            raise ValueError(f"expected picks of shape ({b}, P, 2), got {tuple(picks.shape)}")
        p = picks.shape[1]
        picks = as_pixels(picks.reshape(b * p, -1), b * p, current.shape[-2:]).reshape(b, p, 2)
        picks = picks.to(current.device)
        chunk = inference_chunk(current.device)
        if torch.is_grad_enabled() or b <= chunk:
            return self.transport.place_maps(current, goal, picks, goal_features)
        if goal_features is None and _require(goal).shape[0] == 1:
            goal_features = self.transport.goal_features(goal)  # one shared goal: encode it once
        out = []
        for lo in range(0, b, chunk):
            hi = lo + chunk
            if goal_features is None:
                out.append(self.transport.place_maps(current[lo:hi], goal[lo:hi], picks[lo:hi]))
            else:
                features = goal_features if goal_features.shape[0] == 1 else goal_features[lo:hi]
                out.append(self.transport.place_maps(current[lo:hi], None, picks[lo:hi], features))
        return torch.cat(out)

    def forward(
        self, current: torch.Tensor, goal: torch.Tensor, pick_pixels: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(pick logits (B, H, W), place logits (B, R, H, W) at ``pick_pixels``)."""
        return self.pick_logits(current, goal), self.place_map(current, goal, pick_pixels)

    def loss(
        self,
        current: torch.Tensor,
        goal: torch.Tensor,
        pick_pixels: torch.Tensor,
        place_pixels: torch.Tensor,
        rot_bins: torch.Tensor,
    ) -> dict[str, torch.Tensor]:
        """Training losses; the transport is evaluated at the labelled pick (teacher forcing)."""
        return labelled_loss(self, current, goal, pick_pixels, place_pixels, rot_bins)

    @torch.no_grad()
    def act(
        self, current: torch.Tensor, goal: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, dict[str, torch.Tensor]]:
        """Greedy action: argmax pick, then argmax place and rotation bin at that pick.

        Returns pick (B, 2), place (B, 2), rotation bin of a full turn (B,) and maps {"pick": (B, H, W)
        logits, "place": (B, R, H, W) logits}.
        """
        return greedy_action(self, current, goal)


def labelled_loss(
    model, current: torch.Tensor, goal: torch.Tensor, pick_pixels: torch.Tensor, place_pixels: torch.Tensor,
    rot_bins: torch.Tensor,
) -> dict[str, torch.Tensor]:  # fmt: skip
    """:meth:`GCTN.loss` for any model with ``pick_logits`` and ``place_map``: :func:`gctn_loss` of its maps
    against the labels, the transport evaluated at the labelled pick (teacher forcing)."""
    b, shape = current.shape[0], current.shape[-2:]
    pick = as_pixels(pick_pixels, b, shape).to(current.device)
    place = as_pixels(place_pixels, b, shape).to(current.device)
    pick_logits, place_logits = model.pick_logits(current, goal), model.place_map(current, goal, pick)
    return gctn_loss(pick_logits, place_logits, pick, place, torch.as_tensor(rot_bins).to(current.device))


def greedy_action(model, current: torch.Tensor, goal: torch.Tensor):
    """:meth:`GCTN.act` for any model with ``pick_logits``, ``pick_pixels``, ``place_map`` and
    ``rotation_bins``: the place map is read at the pick where ``pick_pixels`` moves the argmax."""
    pick_logits = model.pick_logits(current, goal)
    pick = model.pick_pixels(current, argmax_pixels(pick_logits)[:, None])[:, 0]
    place_logits = model.place_map(current, goal, pick)
    place, channel = argmax_places(place_logits)
    return pick, place, model.rotation_bins(channel), {"pick": pick_logits, "place": place_logits}


def one_pick_place_map(model, current: torch.Tensor, goal: torch.Tensor | None, pick_pixels: torch.Tensor,
                       goal_features: torch.Tensor | None = None) -> torch.Tensor:  # fmt: skip
    """``place_map`` for any model with ``place_maps``: its place logits (B, R, H, W) at one pick per
    state, as P = 1 of ``place_maps``."""
    pick = as_pixels(pick_pixels, current.shape[0], current.shape[-2:]).to(current.device)
    return model.place_maps(current, goal, pick[:, None], goal_features)[:, 0]


class GctnWrapper(nn.Module):
    """Base of the models that offer a wrapped GCTN's calls with changed maps (:mod:`tvf.models.symmetry`,
    :mod:`tvf.models.goal_mask`, :mod:`tvf.models.pick_centre`): the checkpoint kind, preset, config,
    rotation bins, goal features and picks are the wrapped GCTN's, and so are the maps where a subclass
    keeps them; ``place_map`` and ``act`` follow from the subclass's ``pick_logits`` and
    ``place_maps``."""

    checkpoint_kind = "gctn"

    def __init__(self, gctn: nn.Module) -> None:
        super().__init__()
        self.gctn = gctn
        self.preset = gctn.preset

    def config(self) -> dict:
        return self.gctn.config()

    def rotation_bins(self, channels: torch.Tensor) -> torch.Tensor:
        return self.gctn.rotation_bins(channels)

    def goal_features(self, goal: torch.Tensor) -> torch.Tensor:
        return self.gctn.goal_features(goal)

    def pick_pixels(self, current: torch.Tensor, picks: torch.Tensor) -> torch.Tensor:
        return self.gctn.pick_pixels(current, picks)

    def pick_logits(self, current: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        return self.gctn.pick_logits(current, goal)

    def place_maps(self, current: torch.Tensor, goal: torch.Tensor | None, picks: torch.Tensor,
                   goal_features: torch.Tensor | None = None) -> torch.Tensor:  # fmt: skip
        return self.gctn.place_maps(current, goal, picks, goal_features)

    def place_map(
        self,
        current: torch.Tensor,
        goal: torch.Tensor | None,
        pick_pixels: torch.Tensor,
        goal_features: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Place logits (B, R, H, W) at one pick per state (see :meth:`GCTN.place_map`)."""
        return one_pick_place_map(self, current, goal, pick_pixels, goal_features)

    @torch.no_grad()
    def act(self, current: torch.Tensor, goal: torch.Tensor):
        """Greedy action of the wrapper's maps (see :meth:`GCTN.act`)."""
        return greedy_action(self, current, goal)
