"""Thread-private mpmath: each thread computes in a context of its own (:func:`mp_context`, :data:`thread_mp`)
and hands results out as mpmath's global numbers (:func:`export_mpf`)."""

from __future__ import annotations

import threading

import mpmath as mp
import numpy as np

# -- thread-private mpmath ---------------------------------------------------------------------------------------------
_LOCAL = threading.local()


def mp_context():
    """This thread's private mpmath context.

    mpmath's global context ``mpmath.mp`` is process-wide: a ``workdps`` block in one thread changes the precision
    of every other thread's arithmetic. lieseries computes in a context of its own per thread, and hands results out
    as ordinary ``mpmath.mpf`` (:func:`export_mpf`).
    """
    ctx = getattr(_LOCAL, "ctx", None)
    if ctx is None:
        ctx = _LOCAL.ctx = mp.MPContext()
    return ctx


class _ThreadMP:
    """mpmath's API on this thread's private context (:func:`mp_context`): ``thread_mp.workdps(50)``,
    ``thread_mp.mpf``, ``thread_mp.ellipk``, ... behave like ``mpmath.mp``'s but touch no other thread."""

    def __getattr__(self, name):
        try:
            return getattr(mp_context(), name)
        except AttributeError:
            return getattr(mp, name)


#: Use as ``from lieseries.precision import thread_mp as mp`` inside the engines.
thread_mp = _ThreadMP()


def export_mpf(value, prec: int | None = None):
    """``value`` (an mpf/mpc of any context, or nested lists/tuples/dicts/object arrays of them) as mpmath's global
    ``mpf``/``mpc``, with its value unchanged (or rounded to ``prec`` bits when given), without touching the global
    precision."""
    if hasattr(value, "_mpf_"):
        raw = value._mpf_ if prec is None else mp.libmp.mpf_pos(value._mpf_, prec, mp.libmp.round_nearest)
        return mp.make_mpf(raw)
    if hasattr(value, "_mpc_"):
        re_, im_ = value._mpc_
        if prec is not None:
            re_ = mp.libmp.mpf_pos(re_, prec, mp.libmp.round_nearest)
            im_ = mp.libmp.mpf_pos(im_, prec, mp.libmp.round_nearest)
        return mp.make_mpc((re_, im_))
    if isinstance(value, np.ndarray) and value.dtype == object:
        out = np.empty(value.shape, dtype=object)
        for idx, v in np.ndenumerate(value):
            out[idx] = export_mpf(v, prec)
        return out
    if isinstance(value, list):
        return [export_mpf(v, prec) for v in value]
    if isinstance(value, tuple):
        return tuple(export_mpf(v, prec) for v in value)
    if isinstance(value, dict):
        return {k: export_mpf(v, prec) for k, v in value.items()}
    return value
