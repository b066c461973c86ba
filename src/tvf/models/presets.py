"""Model size presets: ``paper`` (reference widths), ``lite`` (2-core CPU), ``smoke`` (tests).

All presets keep 160 x 160 images and 36 rotations; they differ in widths, the transport crop and
the visual-foresight padding. Measured costs are in docs/models.md.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any

from tvf.errors import TvfError

VF_HEADS = ("image", "blend", "local")
GCTN_KERNELS = ("plain", "c4")
LATER_DEFAULTS: dict[str, Any] = {"gctn_kernels": "plain"}
"""Fields added after presets were first stored, with their defaults. :meth:`ModelPreset.as_dict` leaves
them out at these values, so every run and checkpoint made before them keeps its exact stored preset
(a resume and a checkpoint check compare it)."""


class PresetError(TvfError, ValueError):
    """An unknown preset name or an invalid preset field."""


@dataclass(frozen=True)
class ModelPreset:
    """Hyper-parameters that fix the shapes of the GCTN and VF networks.

    Attributes:
        name: preset name.
        attention_width: width multiplier of the GCTN attention (pick) FCN.
        transport_width: width multiplier of the three transport (place) FCNs.
        vf_width: width multiplier of the visual-foresight FCN.
        image_size: side of the square RGB-H images (pixels).
        n_rotations: rotation bins of a full turn; bin ``i`` is yaw ``i * 2*pi / n_rotations``.
        symmetry: the moved objects look the same after a turn of ``2*pi / symmetry`` (4 for the
            cubic blocks). The transport then scores only the ``n_rotations // symmetry`` bins of one
            period, centred on no turn (docs/models.md, "Rotational symmetry").
        crop: side of the transport kernel cut around the pick (pixels, a multiple of 8).
        transport_channels: feature channels of the key / query / goal maps.
        pad_features: the transport FCNs run on the image and their feature maps are zero-padded by
            ``crop / 2``; otherwise (the reference) the image is padded and the FCNs run on the
            larger map, which costs (1 + crop / image_size)^2 as much.
        correlation: "fft" or "conv" cross-correlation of the transport.
        vf_window: side of the VF pick / place masks (pixels).
        vf_pad: zero (= mean value) padding around the VF input, cropped off after the FCN.
        vf_residual: the VF predicts a change added to the input image instead of the image itself.
        vf_head: "image" (the reference: the FCN draws the next image), "blend" (the FCN edits the
            input: per pixel a softmax over keep-the-input, the pasted place window and a redrawn
            value, so untouched pixels stay exact; docs/models.md), "local" (the FCN redraws only the
            pick and place windows; every other pixel is the input's).
        channels_last: run the convolutions in the channels-last memory format.
        gctn_kernels: "plain" (the paper's) or "c4": the GCTN's FCNs tie every kernel over quarter
            turns (:mod:`tvf.models.c4`), so its maps are exactly equivariant to quarter turns of the
            scene by construction, at the cost of the plain FCNs with the same channels.
    """

    name: str
    attention_width: float
    transport_width: float
    vf_width: float
    image_size: int = 160
    n_rotations: int = 36
    symmetry: int = 1
    crop: int = 64
    transport_channels: int = 3
    pad_features: bool = False
    correlation: str = "fft"
    vf_window: int = 44
    vf_pad: int = 22
    vf_residual: bool = False
    vf_head: str = "image"
    channels_last: bool = True
    gctn_kernels: str = "plain"

    def __post_init__(self) -> None:
        if self.crop % 8 or self.image_size % 8:
            raise PresetError("crop and image_size must be multiples of 8 (the transport FCN is 8s)")
        if (self.image_size + 2 * self.vf_pad) % 4:
            raise PresetError("image_size + 2 * vf_pad must be a multiple of 4 (the VF FCN is 4s)")
        if self.correlation not in ("fft", "conv"):
            raise PresetError(f"correlation must be 'fft' or 'conv', not {self.correlation!r}")
        if self.symmetry < 1 or self.n_rotations % self.symmetry:
            raise PresetError(
                f"symmetry must be a positive divisor of n_rotations ({self.n_rotations}), "
                f"not {self.symmetry}"
            )
        if self.vf_head not in VF_HEADS:
            raise PresetError(f"vf_head must be one of {', '.join(VF_HEADS)}, not {self.vf_head!r}")
        if self.vf_window % 2:
            raise PresetError("vf_window must be even")
        if self.gctn_kernels not in GCTN_KERNELS:
            raise PresetError(
                f"gctn_kernels must be one of {', '.join(GCTN_KERNELS)}, not {self.gctn_kernels!r}"
            )

    def as_dict(self) -> dict[str, Any]:
        """Plain dict (JSON- and ``torch.load(weights_only=True)``-safe); fields of
        :data:`LATER_DEFAULTS` at their defaults are left out."""
        return {k: v for k, v in asdict(self).items() if k not in LATER_DEFAULTS or LATER_DEFAULTS[k] != v}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ModelPreset:
        """Inverse of :meth:`as_dict`; unknown keys raise :class:`PresetError`."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise PresetError(f"unknown preset fields: {unknown}")
        return cls(**data)

    @property
    def place_rotations(self) -> int:
        """Rotation channels of the place map: the bins of one symmetry period."""
        return self.n_rotations // self.symmetry

    def replace(self, **changes: Any) -> ModelPreset:
        """A copy with some fields changed."""
        return ModelPreset.from_dict({**self.as_dict(), **changes})


PAPER = ModelPreset(name="paper", attention_width=1.0, transport_width=1.0, vf_width=1.0)
LITE = ModelPreset(
    name="lite",
    attention_width=0.125,
    transport_width=0.125,
    vf_width=0.25,
    crop=64,
    vf_pad=0,
    symmetry=4,
    pad_features=True,
)
SMOKE = ModelPreset(
    name="smoke", attention_width=0.0625, transport_width=0.0625, vf_width=0.0625, crop=32, vf_pad=0
)
PRESETS: dict[str, ModelPreset] = {p.name: p for p in (PAPER, LITE, SMOKE)}


def get_preset(name: str) -> ModelPreset:
    """Preset by name; unknown names raise :class:`PresetError` listing the choices."""
    try:
        return PRESETS[name]
    except KeyError:
        raise PresetError(f"unknown model preset {name!r}; choose one of {sorted(PRESETS)}") from None


@dataclass(frozen=True)
class LatentPreset:
    """Sizes and loss of the latent-dynamics baseline (:mod:`tvf.models.latent`), per model preset.

    Kept apart from :class:`ModelPreset`: a new field there would change the stored preset of every
    GCTN and VF run, and a resume compares it exactly.

    Attributes:
        width: width multiplier of the encoder, transition and decoder channels.
        channels: channels of the 10 x 10 latent grid (one cell per 16 x 16 pixels).
        recon_weight: loss weight of the current image's reconstruction (squared error).
        latent_weight: loss weight of the next latent's squared distance to the next image's encoding.
    """

    width: float
    channels: int
    recon_weight: float = 1.0
    latent_weight: float = 1.0

    def __post_init__(self) -> None:
        if not self.width > 0 or self.channels < 1:
            raise PresetError(f"a latent preset needs width > 0 and channels >= 1, not {self}")
        for name in ("recon_weight", "latent_weight"):
            if not getattr(self, name) >= 0:
                raise PresetError(f"latent {name} must be 0 or more, not {getattr(self, name)}")

    def as_dict(self) -> dict[str, Any]:
        """Plain dict (stored in the latent model's checkpoints beside the model preset)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> LatentPreset:
        """Inverse of :meth:`as_dict`; unknown keys raise :class:`PresetError`."""
        unknown = sorted(set(data) - {f.name for f in fields(cls)})
        if unknown:
            raise PresetError(f"unknown latent preset fields: {unknown}")
        return cls(**data)


LATENT_PRESETS: dict[str, LatentPreset] = {
    "paper": LatentPreset(width=1.0, channels=32),
    "lite": LatentPreset(width=0.5, channels=16),
    "smoke": LatentPreset(width=0.5, channels=8),
}
"""The latent baseline's sizes for each model preset (docs/models.md, "Latent-dynamics baseline")."""


def get_latent_preset(name: str) -> LatentPreset:
    """The latent baseline's sizes for model preset ``name``; unknown names raise :class:`PresetError`."""
    try:
        return LATENT_PRESETS[name]
    except KeyError:
        raise PresetError(
            f"no latent-dynamics sizes for preset {name!r}; choose one of {sorted(LATENT_PRESETS)}"
        ) from None
