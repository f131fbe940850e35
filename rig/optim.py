"""What every iterative routine of jnr shares: the progress-callback type, freezing a module and the torch
thread count of a block.

Training (:mod:`rig.skinning`) and fitting (:mod:`pipeline.fitting`) report progress through the same
callable, ``progress(stage, iteration, iterations)``, with ``iteration`` counting from 1 to
``iterations`` within the named stage, so one progress bar serves them all.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager

import torch

Progress = Callable[[str, int, int], None]
"""``progress(stage, iteration, iterations)``: called after each step; ``1 <= iteration <= iterations``."""


@contextmanager
def frozen(*modules: torch.nn.Module | None) -> Iterator[None]:
    """Turn off ``requires_grad`` of every parameter of ``modules`` (``None`` entries are skipped) inside
    the block, and turn it back on after, also when the block raises.

    Example:
        >>> decoder = torch.nn.Linear(2, 2)
        >>> with frozen(decoder):
        ...     assert not decoder.weight.requires_grad
        >>> decoder.weight.requires_grad
        True
    """
    params = [p for m in modules if m is not None for p in m.parameters()]
    for p in params:
        p.requires_grad_(False)
    try:
        yield
    finally:
        for p in params:
            p.requires_grad_(True)


@contextmanager
def torch_threads(count: int | None) -> Iterator[None]:
    """Run the block with ``count`` torch intra-op threads (``None``: unchanged) and restore the caller's
    count after, also when the block raises.

    Example:
        >>> before = torch.get_num_threads()
        >>> with torch_threads(1):
        ...     assert torch.get_num_threads() == 1
        >>> torch.get_num_threads() == before
        True
    """
    before = torch.get_num_threads()
    if count is not None:
        torch.set_num_threads(count)
    try:
        yield
    finally:
        torch.set_num_threads(before)
