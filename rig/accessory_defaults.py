"""Defaults of accessory skinning (:func:`rig.accessory.transfer_skinning`), in a module without torch so
that ``jnr --help`` can show them without importing the rig's numerics."""

DEFAULT_FALLOFF_MM = 10.0
"""Contact falloff (mm): expression offsets are followed fully up to half of it from the skin, not at all
beyond it (a glasses rim sits 12-20 mm in front of the eyelids, a cap 3-6 mm off the scalp)."""
DEFAULT_SMOOTHING_MM = 5.0
"""Width (sigma, mm) of the Gaussian kernel that smooths weights and offsets over the accessory, chosen on
the shipped glasses and cap: without it rigid parts tear apart, wider kernels let contact points drift from
the skin (the figures: docs/accessories.md)."""
