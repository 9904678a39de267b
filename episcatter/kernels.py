"""Counting Dr.Jit kernels: what one render compiled and launched.

:func:`kernel_log` records ``dr.kernel_history()`` around a block of code;
:class:`KernelLog` reports how many JIT kernels were launched, how many had
to be compiled (not found in Dr.Jit's memory or disk cache), and the compile
time (``codegen_time + backend_time``, milliseconds in the history).

:func:`literal_changes` explains a recompile: it matches each kernel
compiled in one log against the kernels of another with the same source up
to its numeric literals, and lists the literals that differ -- a value of
the frame (camera, light, medium, image size) that entered a kernel as a
constant instead of an opaque parameter (design: speed, new frames).
"""
from __future__ import annotations

import re
import struct
from contextlib import contextmanager
from dataclasses import dataclass, field

import drjit as dr

from rectify._dr import drain_jit_kernels

_HEX = re.compile(r"0x[0-9a-fA-F]{16}")
_INT = re.compile(r"(?<=[ ,<(\[])(-?\d+)(?=[ ,>)\]\n])")
_NAME = re.compile(r"(drjit|optix)_[0-9a-f]{32}")


@dataclass
class KernelLog:
    """The JIT kernels one block launched (``entries``: kernel history dicts,
    ``ir`` read into a string)."""
    entries: list = field(default_factory=list)

    @property
    def launched(self) -> int:
        return len(self.entries)

    @property
    def compiled(self) -> int:
        return sum(1 for k in self.entries if not k.get("cache_hit"))

    @property
    def compiled_from_disk(self) -> int:
        return sum(1 for k in self.entries if k.get("cache_hit") and k.get("cache_disk"))

    @property
    def compile_seconds(self) -> float:
        return sum(float(k.get("codegen_time", 0.0)) + float(k.get("backend_time", 0.0))
                   for k in self.entries if not k.get("cache_hit")) / 1000.0

    def summary(self) -> dict:
        return {"launched": self.launched, "compiled": self.compiled,
                "compile_s": round(self.compile_seconds, 4)}


def _ir_text(entry) -> str:
    ir = entry.get("ir")
    if ir is None:
        return ""
    return ir.getvalue() if hasattr(ir, "getvalue") else str(ir)


@contextmanager
def kernel_log():
    """Record the JIT kernels launched inside the block into a KernelLog.

    Flushes (``dr.eval``/``dr.sync_thread``) nothing itself: evaluate what
    the block computes inside it."""
    log = KernelLog()
    was = dr.flag(dr.JitFlag.KernelHistory)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()                       # drop what came before
    try:
        yield log
    finally:
        dr.sync_thread()
        hist = drain_jit_kernels()
        dr.set_flag(dr.JitFlag.KernelHistory, was)
        for k in hist:
            k = dict(k)
            k["ir"] = _ir_text(k)
            log.entries.append(k)


def _shape(ir: str) -> str:
    return _INT.sub("#", _HEX.sub("#", _NAME.sub("K", ir)))


def _literals(ir: str) -> list:
    body = _NAME.sub("K", ir)
    out = []
    for m in re.finditer(r"0x[0-9a-fA-F]{16}|(?<=[ ,<(\[])-?\d+(?=[ ,>)\]\n])", body):
        tok = m.group(0)
        if tok.startswith("0x"):
            out.append(struct.unpack(">d", bytes.fromhex(tok[2:]))[0])
        else:
            out.append(int(tok))
    return out


def literal_changes(before: KernelLog, after: KernelLog) -> list:
    """For each kernel compiled in ``after``: (index in after, [(old, new)
    literal pairs]) against a kernel of ``before`` with the same source up
    to literals, or (index, None) when no kernel of ``before`` has its shape
    (a structural change: another code path, loop count or array layout)."""
    by_shape = {}
    for k in before.entries:
        by_shape.setdefault(_shape(k["ir"]), []).append(k)
    out = []
    for i, k in enumerate(after.entries):
        if k.get("cache_hit"):
            continue
        cands = by_shape.get(_shape(k["ir"]))
        if not cands:
            out.append((i, None))
            continue
        new = _literals(k["ir"])
        best = None
        for c in cands:
            old = _literals(c["ir"])
            diff = [(a, b) for a, b in zip(old, new) if a != b]
            if best is None or len(diff) < len(best):
                best = diff
        out.append((i, best))
    return out


@contextmanager
def launch_sites(roots=("integrators", "rectify"), sequence: list | None = None):
    """Count the JIT kernels launched inside the block by the source line
    that launched them: a ``Counter`` of ``"path:line function"`` (paths
    under one of ``roots``, relative to the repository); ``sequence``: a
    list that gets ``(site, lanes)`` of every kernel in launch order (what
    to fuse next: neighbours of one width).

    A kernel runs when a line needs an array's values (a read-back, a
    gather or scatter from an unevaluated array, ``dr.eval``); this traces
    every line of the ``roots`` packages (``sys.settrace``: slow, for
    diagnosis) and charges the kernels launched since the last line event
    to the line of ours that was running -- after a call into one of our
    functions returns, to the caller's line.  Owns the kernel history
    while it runs."""
    import collections
    import os
    import sys

    top = os.path.dirname(os.path.dirname(os.path.abspath(__file__))) + os.sep
    prefixes = tuple(top + r + os.sep for r in roots)
    sites = collections.Counter()
    last = ["<before the first traced line>"]

    def charge():
        kernels = drain_jit_kernels()
        if kernels:
            sites[last[0]] += len(kernels)
            if sequence is not None:
                sequence.extend((last[0], k.get("size")) for k in kernels)

    def where(frame) -> str:
        return f"{frame.f_code.co_filename[len(top):]}:{frame.f_lineno} {frame.f_code.co_name}"

    def local(frame, event, arg):
        if event == "line":
            charge()
            last[0] = where(frame)
        elif event == "return":
            charge()
            caller = frame.f_back
            if caller is not None and caller.f_code.co_filename.startswith(prefixes):
                last[0] = where(caller)
        return local

    def tracer(frame, event, arg):
        return local if frame.f_code.co_filename.startswith(prefixes) else None

    was = dr.flag(dr.JitFlag.KernelHistory)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()
    previous = sys.gettrace()
    sys.settrace(tracer)
    try:
        yield sites
    finally:
        sys.settrace(previous)
        dr.sync_thread()
        charge()
        dr.set_flag(dr.JitFlag.KernelHistory, was)
