"""tvf: Transporters with Visual Foresight for pick-and-place rearrangement."""

__version__ = "0.1.0"
