"""What a device test checks of a call: that it creates no tensor on an implicit device.

A tracker that runs on the device of its inputs (``pmsr evaluate --device cuda``) must give every
tensor it makes that device (``device=x.device``, ``x.new_*``, ``*_like``). One it makes with
torch's default device instead lands on the CPU, and the call breaks on a GPU only. This machine
has none, so :func:`on_meta_default` runs the call with its inputs on the CPU while the tensors
made without ``device=`` go to the meta device (as under ``torch.set_default_device("meta")``):
such a tensor has shapes and no data, so mixing it with a CPU input raises ("Tensor on device
meta is not on the expected device cpu"), and so does reading it (``.item()``, ``.tolist()``,
``.numpy()``). Tensors that share memory with their source (``torch.from_numpy``) stay on the CPU
and are not caught: they are the static test's (tests/test_device_agnostic.py).

A hole the check leaves: indexing a CPU tensor with a meta index tensor gives uninitialised
numbers rather than an error, so a device test also compares the call's answer with the same call
made as usual, bit for bit.

One departure from torch's default device: ``torch.as_tensor(t)`` / ``torch.asarray(t)`` of a
tensor ``t`` without ``device=`` keeps ``t``'s device here (what it does on a GPU run, whose
default device stays the CPU), where the default device would move it.

:func:`implicit_factories` is the diagnosis: the lines of a call that make tensors without
``device=``, all of them in one call (the meta check stops at the first).
"""

from __future__ import annotations

import traceback
from typing import Callable, TypeVar

import torch
from torch.overrides import TorchFunctionMode

T = TypeVar("T")

FACTORIES = frozenset({torch.arange, torch.as_tensor, torch.asarray, torch.empty, torch.empty_strided, torch.eye,
                       torch.full, torch.linspace, torch.logspace, torch.ones, torch.rand, torch.randint, torch.randn,
                       torch.randperm, torch.scalar_tensor, torch.tensor, torch.tril_indices, torch.triu_indices,
                       torch.zeros})
"""Functions that make a tensor on the default device unless given ``device=`` (the ``*_like`` and
``Tensor.new_*`` ones follow their argument's device)."""


def _implicit(func, args, kwargs) -> bool:
    """Whether ``func(*args, **kwargs)`` makes a tensor on the default device."""
    if func not in FACTORIES or kwargs.get("device") is not None:
        return False
    return not (func in (torch.as_tensor, torch.asarray) and args and isinstance(args[0], torch.Tensor))


class _ToMeta(TorchFunctionMode):
    """Tensors made without ``device=`` go to the meta device."""

    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = dict(kwargs or {})
        if _implicit(func, args, kwargs):
            kwargs["device"] = "meta"
        return func(*args, **kwargs)


class _Record(TorchFunctionMode):
    """Records where tensors are made without ``device=`` (the innermost frame under ``pmsr_nn``)."""

    def __init__(self):
        super().__init__()
        self.found: dict[str, int] = {}

    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        if _implicit(func, args, kwargs):
            frames = [f for f in traceback.extract_stack()[:-1] if "/pmsr_nn/" in f.filename]
            if frames:
                f = frames[-1]
                key = f"{f.filename.split('/pmsr_nn/')[-1]}:{f.lineno} torch.{func.__name__}: {f.line}"
                self.found[key] = self.found.get(key, 0) + 1
        return func(*args, **kwargs)


def on_meta_default(fn: Callable[..., T], *args, **kwargs) -> T:
    """``fn(*args, **kwargs)`` with the tensors it makes without ``device=`` on the meta device;
    torch is as before when the call returns or raises."""
    with _ToMeta():
        return fn(*args, **kwargs)


def implicit_factories(fn: Callable, *args, **kwargs) -> dict[str, int]:
    """``"file:line torch.f: source" -> calls`` for every line under ``pmsr_nn`` that made a tensor
    without ``device=`` during ``fn(*args, **kwargs)`` (run as usual, on the CPU)."""
    mode = _Record()
    with mode:
        fn(*args, **kwargs)
    return mode.found
