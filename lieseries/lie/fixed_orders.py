"""The fixed-point expansion (:mod:`lieseries.lie.fixed`): the jet plan's instructions prepared, the orders run.

Order 0 runs the step functions of the plan's instructions (:mod:`lieseries.lie.fixed_steps`), which fix every
exponent, shift and constant; the orders k >= 1 run as one generated Python function (:func:`_order_loop`, cached
per structure) that writes the sums of products and the packed dot products out over local variables and calls
the other steps.  Products sharing an operand are packed into one dot product up to :data:`_GMP_GROUP_BITS`
(gmpy2) or :data:`_INT_GROUP_BITS` (Python ints) working bits, and computed separately, each once per order, above.
"""

from __future__ import annotations

import math
import weakref
from itertools import chain
from operator import mul as _mul
from time import perf_counter as _clock

from mpmath.libmp import fzero, mpf_add, mpf_mul, mpf_sub

from ..expr import RND
from . import bigint
from .bigint import bit_length_function, div_round, eraw, to_int
from .fixed_steps import (
    Dots,
    Run,
    mk_atan,
    mk_div,
    mk_exp,
    mk_lin,
    mk_log,
    mk_mul,
    mk_pow,
    mk_scale,
    mk_sincos,
    mk_sop,
    mk_sqr,
    mk_sqrt,
    mk_tan,
)
from .plan import DeadlineExceeded, jet_plan

def _cprod(cv, slots):
    """The exact product of constant slots (None for none)."""
    if not slots:
        return None
    r = cv[slots[0]]
    for x in slots[1:]:
        r = mpf_mul(r, cv[x])
    return r


def _arg_slots(ins):
    """The slots an instruction reads."""
    kind, out, args, extra = ins
    if kind == "lin":
        return [x for x, _ in args]
    if kind == "sop":
        return [x for a, b, *_ in args[0] for x in (a, b)] + [a for a, *_ in args[1]]
    if kind == "dots":
        return [args[0], *args[1]]
    return list(args)


def _use_counts(instrs, outputs) -> dict:
    """How many times each slot is read: by the instructions, and once more for each output."""
    used = {}
    for ins in instrs:
        for x in _arg_slots(ins):
            used[x] = used.get(x, 0) + 1
    for o in outputs:
        used[o] = used.get(o, 0) + 1
    return used


#: Working precisions (bits) up to which products sharing an operand are packed into one dot product
#: (:func:`_group`), with Python ints and with gmpy2: above them a packed product, half of whose bits are the
#: fields' headroom, costs more than the separate products it replaces (gmpy2: 1.7 against 1.3 us per term
#: at 800 bits, 18 against 10 at 3500 bits, 7 partners).
_INT_GROUP_BITS = 400
_GMP_GROUP_BITS = 1000


def _group(instrs, enabled=True):
    """Insert ``dots`` steps: the products of the ``sop`` steps that share an operand, computed together at the
    first step that needs one of them (when both operands are computed by then); none when not ``enabled``."""
    pos = {}
    for i, ins in enumerate(instrs):
        outs = ins[1] if isinstance(ins[1], tuple) else (ins[1],)
        for o in outs:
            pos[o] = i
    count = {}
    prods = []  # (consumer index, term index, a, b)
    for i, ins in enumerate(instrs):
        if ins[0] == "sop":
            for t, (a, b, c, ng) in enumerate(ins[2][0]):
                prods.append((i, t, a, b))
                for x in {a, b}:
                    count[x] = count.get(x, 0) + 1
    groups = {}
    for i, t, a, b in (prods if enabled else ()):
        pv, pt = (a, b) if (count[a], -a) >= (count[b], -b) else (b, a)
        groups.setdefault(pv, []).append((i, t, pt))
    at = {}  # instruction index -> dots steps to run before it
    keyed = {}
    nkeys = 0
    for pv, members in groups.items():
        P = min(i for i, _, _ in members)
        ready = [m for m in members if pos.get(pv, -1) < P and pos.get(m[2], -1) < P]
        partners = list(dict.fromkeys(m[2] for m in ready))  # a product used twice is computed once
        if len(partners) < 2:
            continue
        keys = tuple(range(nkeys, nkeys + len(partners)))
        nkeys += len(partners)
        key_of = dict(zip(partners, keys))
        for i, t, pt in ready:
            keyed[(i, t)] = key_of[pt]
        at.setdefault(P, []).append(("dots", None, (pv, tuple(partners)), keys))
    out = []
    for i, ins in enumerate(instrs):
        out.extend(at.get(i, ()))
        if ins[0] == "sop":
            prods_i = tuple((a, b, c, ng, keyed.get((i, t))) for t, (a, b, c, ng) in enumerate(ins[2][0]))
            ins = ("sop", ins[1], (prods_i, ins[2][1]), ins[3])
        out.append(ins)
    return out, nkeys


_FUSED = weakref.WeakKeyDictionary()  # jet plan -> its fused instructions


def _fuse(plan):
    """The plan's instructions with every lin whose terms are single-use products (possibly scaled by a
    constant) or scaled slots turned into one ``sop`` instruction."""
    uses = {}

    def use(x):
        uses[x] = uses.get(x, 0) + 1

    for kind, out, args, extra in plan.instrs:
        if kind == "lin":
            for x, _ in args:
                use(x)
        else:
            for x in args:
                use(x)
    for o in plan.outputs:
        use(o)
    producer = {}
    for ins in plan.instrs:
        kind, out = ins[0], ins[1]
        if kind in ("mul", "sqr", "scale"):
            producer[out] = ins
    fused = set()
    new = []

    def unscale(a, b, cs, ng):
        """A product term with scaled operands (c y) written as c (y * ...)."""
        ops = []
        for x in (a, b):
            p = producer.get(x)
            while p is not None and p[0] == "scale":
                cs = cs + (p[3],)
                x = p[2][0]
                p = producer.get(x)
            ops.append(x)
        return ops[0], ops[1], cs, ng

    for ins in plan.instrs:
        kind, out, args, extra = ins
        if kind != "lin":
            new.append(ins)
            continue
        prods, lins = [], []
        for v, ng in args:
            p = producer.get(v) if uses.get(v) == 1 else None
            if p is not None and p[0] == "scale":
                inner = producer.get(p[2][0]) if uses.get(p[2][0]) == 1 else None
                if inner is not None and inner[0] in ("mul", "sqr"):
                    fused.update((v, inner[1]))
                    a = inner[2][0]
                    b = inner[2][1] if inner[0] == "mul" else a
                    prods.append(unscale(a, b, (p[3],), ng))
                else:
                    fused.add(v)
                    lins.append((p[2][0], (p[3],), ng))
            elif p is not None and p[0] in ("mul", "sqr"):
                fused.add(v)
                a = p[2][0]
                b = p[2][1] if p[0] == "mul" else a
                prods.append(unscale(a, b, (), ng))
            else:
                lins.append((v, (), ng))
        new.append(("sop", out, (tuple(prods), tuple(lins)), extra))
    new = [ins for ins in new if ins[1] not in fused or ins[0] == "sop"]
    # scalings whose every use moved into products are dropped
    while True:
        used = _use_counts(new, plan.outputs)
        keep = [ins for ins in new if ins[0] != "scale" or used.get(ins[1])]
        if len(keep) == len(new):
            return new
        new = keep



# --------------------------------------------------------------------------
# The expansion
# --------------------------------------------------------------------------

def _state_exponents(y0_raw):
    es = [eraw(r) for r in y0_raw]
    nz = [e for e in es if e is not None]
    fallback = min(nz) if nz else 0
    return [fallback if e is None else e for e in es]


# --------------------------------------------------------------------------
# The orders k >= 1 as one generated function
# --------------------------------------------------------------------------

_LOOPS = {}  # the structure of an expansion's orders -> its generated function


def _order_loop(steps, deferred, rest, checked, Z):
    """(run, env): ``run(k0, order, deadline, env)`` computes the orders k0..order-1 of an expansion whose order 0
    the steps have computed (it fixed every exponent, shift and constant).  The ``sop`` and ``dots`` steps are
    written out as straight-line Python over local variables (the same integer operations as their step
    functions, without their per-term loops and lookups), the other steps are called; the function is generated
    once per structure (the instructions and which constant factors are -1, 1 or other) and cached.  With
    ``checked`` the packed dot products check their fields' width at every order (:class:`Dots`); without, the
    caller checks it once at the end (:meth:`Dots.all_fit`), the fields are read with half a field added to each and
    every sum of products that reads them subtracts the halves at once, as a constant ``K`` of its own.  The
    environment's big constants are of the integer type ``Z``, as the jets are (gmpy2 converts a Python int
    operand at every operation)."""
    sig, env = [], []
    put = env.append  # the values in the order of their names (_env_names)
    half_of = {}  # a dot product's key -> what its field holds above it (without checks)

    for j, st in enumerate(steps):
        kind = getattr(st, "kind", None)
        if kind == "dots":
            env += (st, st.A, st.P, *st.Bs)  # o, a, p, b_m
            paired = st.dot.paired
            if paired:
                put(st.dot)
            if not checked:
                put(st.bias_all)
                half_of.update(dict.fromkeys(st.keys, st.half if len(st.Bs) > 1 else 0))
            sig.append(("d", len(st.Bs), paired, tuple(st.keys)))
        elif kind == "sop":
            tsig = []
            K = 0
            jets = True  # (linear terms alone)
            for A, B, cm, d in st.terms:
                if B is not None:
                    src = "call"
                    put(B)
                    jets = False
                elif A.__class__ is int:
                    src = A  # a dot product's key
                    jets = False
                    if not checked:  # the term reads its field plus half: minus (half times its factor) << d
                        K -= (half_of[A] if cm is None else half_of[A] * cm) << d
                else:
                    src = "jet"
                    put(A)
                if cm is not None and cm != -1:
                    put(cm)  # cm_m
                put(d)  # d_m
                # (cm depends on the constants only; the shifts depend on the state's exponents and are variables,
                # so that one function serves every step)
                tsig.append((src, None if cm is None else (-1 if cm == -1 else 0)))
            fin = st.fin
            if st.state is None:  # round(tot / 2**fin)
                put(st.C)  # C, hf
                put(Z(1) << (fin - 1) if fin > 0 else 0)
                fp = fin > 0
            else:  # round(tot 2**fin / (k + 1)) = floor((tot 2**e + k + 1) / (2 (k + 1))), e = fin + 1
                fin += 1
                fp = fin >= 0
            # The direction of the final shift: with a product among the terms it is a right shift at every step
            # (the terms' exponents hold the F fraction bits of both factors: fin ~ -F), part of the structure;
            # for linear terms alone it follows the state's magnitudes from step to step, a variable fp
            if jets:
                put(fp)  # fp, fin, nf
                put(max(fin, 0))
                put(max(-fin, 0))
                fp = None
            else:
                put(fin if fp else -fin)  # fin or nf
            if K:
                put(K if K.__class__ is Z else Z(K))
            sig.append(("s", st.state, tuple(tsig), bool(K), fp))
        else:
            put(st)
            sig.append(("g",))
    for zi, i in deferred:
        put(zi)
    if rest is not None:
        put(rest)
    key = (tuple(sig), tuple(i for _, i in deferred), rest is not None, checked)
    fn = _LOOPS.get(key)
    if fn is None:
        if len(_LOOPS) >= 256:  # a process that meets many systems: start again
            _LOOPS.clear()
        fn = _LOOPS[key] = _generate(key, _env_names(key))
    return fn, env


def _env_names(key):
    """The names of the values :func:`_order_loop` puts in the environment of a structure, in their order."""
    sig, deferred, rest, checked = key
    names = []
    for j, st in enumerate(sig):
        if st[0] == "d":
            _, n, paired, _keys = st
            names += [f"o{j}", f"a{j}", f"p{j}"] + [f"b{j}_{m}" for m in range(n)]
            if paired:
                names.append(f"c{j}")
            if not checked:
                names.append(f"ball{j}")
        elif st[0] == "s":
            _, state, terms, has_K, fp = st
            for m, (src, cm) in enumerate(terms):
                if src == "call" or src == "jet":
                    names.append(f"t{j}_{m}")
                if cm == 0:
                    names.append(f"cm{j}_{m}")
                names.append(f"d{j}_{m}")
            if state is None:
                names += [f"C{j}", f"hf{j}"]
            names += [f"fp{j}", f"fin{j}", f"nf{j}"] if fp is None else [f"fin{j}" if fp else f"nf{j}"]
            if has_K:
                names.append(f"K{j}")
        else:
            names.append(f"g{j}")
    names += [f"z{i}" for i in deferred]
    if rest:
        names.append("rest")
    return names


def _generate(key, names):
    sig, deferred, rest, checked = key
    head = ["def run(k0, order, deadline, env):", f"    ({', '.join(names)},) = env"]
    body = []
    for j, st in enumerate(sig):
        if st[0] == "d":
            _, n, paired, keys = st
            head.append(f"    W{j}, mask{j}, half{j}, bias{j} = o{j}.W, o{j}.mask, o{j}.half, o{j}.bias")
            if checked:
                head.append(f"    ba{j}, bb{j} = o{j}.ba, o{j}.bb")
                body += [f"x = a{j}[k].bit_length()",
                         f"if x > ba{j}: ba{j} = x",
                         f"x = max({', '.join(f'b{j}_{m}[k].bit_length()' for m in range(n))})" if n > 1 else
                         f"x = b{j}_0[k].bit_length()",
                         f"if x > bb{j}: bb{j} = x",
                         f"need = ba{j} + bb{j} + k1.bit_length() + 2",
                         f"if need > W{j}: W{j}, mask{j}, half{j}, bias{j} = o{j}.repack(k, need)"]
            e = f"b{j}_{n - 1}[k]"
            for m in range(n - 2, -1, -1):
                e = f"(({e}) << W{j}) + b{j}_{m}[k]"
            body.append(f"p{j}.append({e})")
            # (the bias of the fields' reading, when there is one, is the sum's start: one addition fewer)
            bias = "" if n == 1 else f"bias{j}" if checked else f"ball{j}"
            if paired:
                body.append(f"D = c{j}(k)" + (f" + {bias}" if bias else ""))
            else:
                body.append(f"D = sum(map(_mul, a{j}, reversed(p{j}))" + (f", {bias})" if bias else ")"))
            if n == 1:
                body.append(f"dv{keys[0]} = D")
            elif checked:  # the fields of D = the sum + bias (Dots.repack)
                at = ["D", f"(D >> W{j})"] + [f"(D >> {m} * W{j})" for m in range(2, n)]
                top = "D >> " + (f"W{j}" if n == 2 else f"{n - 1} * W{j}")
                body += [f"dv{key_} = ({e} & mask{j}) - half{j}" for key_, e in zip(keys[:-1], at)]
                body.append(f"dv{keys[-1]} = {top}")
            else:  # the fields of D + bias_all, each its sum of products plus half (W fixed: its multiples once)
                head += [f"    W{j}_{m} = {m} * W{j}" for m in range(2, n)]
                at = ["D", f"(D >> W{j})"] + [f"(D >> W{j}_{m})" for m in range(2, n)]
                body += [f"dv{key_} = {e} & mask{j}" for key_, e in zip(keys[:-1], at)]
                body.append(f"dv{keys[-1]} = D >> " + (f"W{j}" if n == 2 else f"W{j}_{n - 1}"))
        elif st[0] == "s":
            _, state, terms, has_K, fp = st
            parts = []
            for m, (src, cm) in enumerate(terms):
                v = f"t{j}_{m}(k)" if src == "call" else (f"t{j}_{m}[k]" if src == "jet" else f"dv{src}")
                if cm == 0:
                    v = f"({v} * cm{j}_{m})"
                parts.append(("- " if cm == -1 else "+ ") + f"({v} << d{j}_{m})")
            tot = " ".join(parts)
            tot = tot[2:] if tot.startswith("+ ") else "-" + tot[2:]
            body.append(f"tot = {tot}" + (f" + K{j}" if has_K else ""))
            if state is None:  # round(tot / 2**fin)
                up, down = f"C{j}.append((tot + hf{j}) >> fin{j})", f"C{j}.append(tot << nf{j})"
                body += [f"if fp{j}: {up}", f"else: {down}"] if fp is None else [up if fp else down]
            else:  # round(tot 2**fin / (k + 1)): floor((tot 2**e + k + 1) / (2 (k + 1))) with e = fin + 1, the same
                # with floor(tot 2**e) for e < 0 (floor(floor(x) / m) = floor(x / m) for an integer m > 0): a shift
                # and a division by a small integer
                up, down = f"nx{state} = ((tot << fin{j}) + k1) // k2", f"nx{state} = ((tot >> nf{j}) + k1) // k2"
                body += [f"if fp{j}: {up}", f"else: {down}"] if fp is None else [up if fp else down]
        else:
            body.append(f"g{j}(k)")
    body += [f"z{i}.append(nx{i})" for i in deferred]
    if rest:
        body.append("rest(k)")
    src = "\n".join(head + ["    for k in range(k0, order):",
                             "        if deadline is not None and _clock() > deadline:",
                             "            raise DeadlineExceeded(k)",
                             "        k1 = k + 1",
                             "        k2 = k1 << 1"] + ["        " + line for line in body]) + "\n"
    scope = {"_clock": _clock, "DeadlineExceeded": DeadlineExceeded, "_mul": _mul}
    exec(compile(src, "<lieseries.lie.fixed_orders>", "exec"), scope)
    return scope["run"]


_PREPARED = weakref.WeakKeyDictionary()  # jet plan -> {(grouped, wp, parameters): prepared instructions}


def _prepared(plan, grouped, wp, pars_raw):
    """(instructions, number of dot-product keys, outputs fused into their state's step, constant values) of a
    plan at ``wp`` bits for the parameters ``pars_raw``: the fused and grouped instructions with their constants
    (offsets of lin/sop steps, the exact constant factors of their terms) evaluated, once per plan, precision and
    parameters."""
    by_plan = _PREPARED.setdefault(plan, {})
    key = (grouped, wp, tuple(pars_raw))
    got = by_plan.get(key)
    if got is not None:
        return got
    cv = plan.constant_values(pars_raw, wp)
    cache = _FUSED.setdefault(plan, {})
    fused = cache.get(grouped)
    if fused is None:
        instrs, nkeys = _group(_fuse(plan), grouped)
        uses = _use_counts(instrs, plan.outputs)
        to_state = {o: i for i, o in enumerate(plan.outputs) if uses[o] == 1}
        fused = cache[grouped] = (instrs, nkeys, to_state)
    instrs, nkeys, to_state = fused
    out = []
    for kind, o, args, extra in instrs:
        if kind in ("lin", "sop"):
            offset = None
            if extra:
                offset = fzero
                for x, ng in extra:
                    offset = (mpf_sub if ng else mpf_add)(offset, cv[x], 2 * wp, RND)
            if kind == "sop":
                args = ([(a, b, _cprod(cv, cs), ng, k) for a, b, cs, ng, k in args[0]],
                        [(a, _cprod(cv, cs), ng) for a, cs, ng in args[1]])
            extra = offset
        out.append((kind, o, args, extra))
    if len(by_plan) >= 16:  # a plan run with many parameter sets or precisions: start again
        by_plan.clear()
    got = by_plan[key] = (out, nkeys, to_state, cv)
    return got


def expand(program, y0_raw, pars_raw, order, wp, s, deadline=None, sizes=None, measured=None, packs=None):
    """Fixed-point jets of the state: (M, U) with ``c_{i,k} = M[i][k] * 2**(U[i] - s*k)``.

    ``wp`` is the working precision in bits (guard bits included), ``s`` the time scale exponent, ``deadline`` an
    optional :func:`time.perf_counter` value checked after every order (:class:`DeadlineExceeded`).  ``sizes``
    (:class:`NodeSizes` of an earlier expansion, or None) gives products and sums of products their exponents from
    the magnitudes their operands carried rather than from their scales alone; a :class:`NodeSizes` given as
    ``measured`` receives this expansion's.  A list given as ``packs`` receives the packed partners of its dot products
    whose partners are all state variables, as (packed coefficients of the orders 0..order-1, field width, the
    partners' state indices, the largest bit length of their coefficients of those orders): every field of the k-th
    integer is the coefficient k of its state (:meth:`~lieseries.lie.fixed.FixedJets.evaluate` reads them).
    """
    sz = sizes.at(s) if sizes is not None else None
    got = _expand(program, y0_raw, pars_raw, order, wp, s, deadline, False, sz, measured, packs)
    if got is None:  # a packed dot product's fields were too narrow for a later order: again, checking every order
        got = _expand(program, y0_raw, pars_raw, order, wp, s, deadline, True, sz, measured, packs)
    return got


class NodeSizes:
    """What the jets of an expansion carried: for every slot the binary exponent of its largest ``|c_k| sigma**k``
    (None for a jet that was zero, or none), and the scale its exponent gave it (F bits above the exponent).

    A scale propagated through products bounds what a node carries from above; where it is far above (a sum whose
    terms cancel, a chain of products of bounds, a node whose value is zero), the node's rounding, a unit of its
    exponent, is that much coarser than the node needs, and the loss is amplified downstream (a mathematically zero
    constraint residual multiplied into the vector field, say).  An expansion given these sizes rounds every
    product and sum of products F bits below what its largest term carried where that is finer than the scales
    give (:meth:`~lieseries.lie.fixed_steps.Run.exponent`); :meth:`at` moves them to another time scale."""

    def __init__(self):
        self.sizes = None
        self.scales = None
        self.nvars = 0
        self.s = None
        self.bits = None
        self.other = (None, None)  # (s, the sizes at s) last computed by at()
        self.zero = []  # the state variables whose value was zero
        self.nodes = False  # whether any node was measured (not every one fused into the states' steps)
        # for every state, the exponents of the error the roundings put into its jet and of its scale (None: nothing
        # to judge; every node fused into the states' steps rounds only there): _rounding_error
        self.errors = None

    def fill(self, run, nvars):
        J, U, F = run.J, run.U, run.F
        self.nvars, self.s = nvars, run.s
        self.zero = [i for i in range(nvars) if J[i] and not J[i][0]]
        self.nodes = any(J[x] and U[x] is not None for x in range(nvars, len(J)))
        if not self.nodes and not self.zero:  # every node fused into the states' steps (which round at the
            return  # states' exponents) and no state at zero: nothing to measure
        bl = bit_length_function()
        n = len(J)
        sizes, scales, bits = [None] * n, [None] * n, [None] * n
        for x, jet in enumerate(J):
            u = U[x]
            if jet and u is not None:
                b = bits[x] = list(map(bl, jet))
                m = max(b)
                scales[x] = u + F
                if m:
                    sizes[x] = u + m
        self.sizes, self.scales, self.bits = sizes, scales, bits

    def at(self, s):
        """The sizes at the time scale ``2**s``: the largest ``|c_k| 2**(s k)`` of every node (None if unknown)."""
        if s == self.s or self.sizes is None:
            return self.sizes
        if self.other[0] != s:
            d = s - self.s
            out = []
            for e, b in zip(self.sizes, self.bits):
                if e is None:
                    out.append(None)
                else:
                    m = e - max(b)  # the node's exponent
                    out.append(m + max(x + d * k for k, x in enumerate(b) if x))
            self.other = (s, out)
        return self.other[1]

    def coarse(self, bits, before=None):
        """Whether a node's scale was more than ``bits`` above what it carried, beyond what ``before`` (the sizes
        the expansion was given, or None) already knew: the expansion, given these sizes, rounds finer."""
        if self.sizes is None:
            return False
        old = before.at(self.s) if before is not None else None
        for x in chain(self.zero, range(self.nvars, len(self.sizes))):
            e = self.sizes[x]
            if e is not None and self.scales[x] - e > bits and (old is None or old[x] is None or old[x] - e > bits):
                return True
        return False


def _rounding_error(instrs, to_state, cv, outputs, run, S):
    """For every state, (a bound on the exponent of the error the expansion's own roundings put into its jet's
    ``|c_k| sigma**k``, the exponent of its scale, or of what it carried where that is larger (``S``:
    :attr:`NodeSizes.sizes`)); (None, None) where nothing can be judged.

    The states' own values enter exact (their rounding to the working precision is the problem's conditioning, the
    same for any arithmetic); every node adds half a unit of its exponent, and errors travel by first-order bounds
    on the operations (a product's error ``E_a + S_b`` and ``E_b + S_a``, a quotient's divided by its denominator's
    value, ...), never cancelling.  Where nothing cancels this is about ``-F`` (F the working bits): each node is
    rounded F bits below what it carries.  Where terms of a sum cancel far below their size -- ``(p + x)^2 - x^2 - 2
    p x`` at x = 6e20 -- the nodes' roundings, F bits below the terms, can be far above what the states'
    derivatives need, and the result is as far off."""
    J, U = run.J, run.U
    bl = bit_length_function()
    S = [_NEG if v is None else v for v in S]  # (a zero jet: nothing)
    E = [_NEG] * len(J)  # the error bound's exponent (-inf: exact)

    def value(x):  # the exponent of |c_0| (divisors: the recurrences divide by it)
        return U[x] + bl(J[x][0])

    out_err = {}
    for kind, out, args, extra in instrs:
        if kind == "sop" or kind == "lin":
            e = _sum_error(kind, args, extra, E, S, U)
            if out in to_state:
                out_err[to_state[out]] = e
            else:
                E[out] = max(e, U[out] - 1)
        elif kind != "dots":
            _op_error(kind, out, args, extra, E, S, U, cv, value)
    s, F = run.s, run.F
    got = []
    for i, o in enumerate(outputs):
        e = out_err[i] if i in out_err else E[o]
        got.append((None, None) if e == _NEG else (e + s, max(S[i], U[i] + F)))
    return got


_NEG = -math.inf


def _sum_error(kind, args, extra, E, S, U):
    """:func:`_rounding_error` of a sum of products (``sop``) or of jets (``lin``) before its own rounding: its
    terms' errors, and the offset's rounding at the finest term's exponent."""
    e, x0 = _NEG, math.inf
    if kind == "sop":
        for a, b, c, _, _ in args[0]:
            ce = 0 if c is None else (c[2] + c[3] if c[1] else None)
            if ce is not None:
                ea, eb = E[a] + S[b], E[b] + S[a]
                e = max(e, (ea if ea > eb else eb) + ce)
                x0 = min(x0, U[a] + U[b] + ce)
        for a, c, _ in args[1]:
            ce = 0 if c is None else (c[2] + c[3] if c[1] else None)
            if ce is not None:
                e, x0 = max(e, E[a] + ce), min(x0, U[a] + ce)
    else:
        for a, _ in args:
            e, x0 = max(e, E[a]), min(x0, U[a])
    if extra is not None and extra[1] and x0 < math.inf:
        e = max(e, x0 - 1)
    return e


def _op_error(kind, out, args, extra, E, S, U, cv, value):
    """:func:`_rounding_error` of the other instructions: ``E`` of their jets."""
    def cexp(c):  # the exponent of a raw constant
        return c[2] + c[3] if c[1] else _NEG

    if kind == "scale":
        E[out] = E[args[0]] + cexp(cv[extra])
    elif kind == "mul" or kind == "sqr":
        a = args[0]
        b = args[1] if kind == "mul" else a
        E[out] = max(E[a] + S[b], E[b] + S[a], U[out] - 1)
    elif kind == "div" or kind == "rdiv":
        b = args[-1]
        d = value(b)
        ea = E[args[0]] - d if kind == "div" else _NEG
        E[out] = max(ea, E[b] + S[out] - d, U[out] - 1)
    elif kind in ("pow", "sqrt", "exp", "log"):  # |d out / d a|: |r out / a|, |out / 2a|, |out|, 1 / |a|
        a = args[0]
        g = S[out] if kind != "log" else 0
        if kind != "exp":
            g -= value(a)
        if kind == "pow":
            g += cexp(cv[extra[0]])
        E[out] = max(E[a] + g + 1, U[out] - 1)
    elif kind == "tan" or kind == "tanh":  # t' = u a', u = 1 +- t^2
        t, u = out
        E[t] = max(E[args[0]] + S[u] + 1, U[t] - 1)
        E[u] = max(E[t] + S[t] + 2, U[u] - 1)
    elif kind == "atan":  # u t' = a', u = 1 + a^2
        t, u = out
        a = args[0]
        E[u] = max(E[a] + S[a] + 2, U[u] - 1)
        E[t] = max(E[a] - value(u) + 1, U[t] - 1)
    else:  # sincos, sinhcosh: |d/da| of each at most the size of the other
        g = E[args[0]] + max(S[o] for o in out) + 1
        for o in out:
            E[o] = max(g, U[o] - 1)


def _steps(run, instrs, to_state, cv, wp):
    """The step of each prepared instruction (:mod:`lieseries.lie.fixed_steps`) over the expansion ``run``."""
    steps = []
    for kind, out, args, extra in instrs:
        if kind == "dots":
            steps.append(Dots(run, args[0], args[1], extra))
        elif kind == "lin":
            steps.append(mk_lin(run, out, args, extra))
        elif kind == "sop":
            steps.append(mk_sop(run, out, args[0], args[1], extra, to_state.get(out)))
        elif kind == "scale":
            steps.append(mk_scale(run, out, args[0], cv[extra]))
        elif kind == "mul":
            steps.append(mk_mul(run, out, args[0], args[1]))
        elif kind == "sqr":
            steps.append(mk_sqr(run, out, args[0]))
        elif kind == "div":
            steps.append(mk_div(run, out, args[0], args[1], wp))
        elif kind == "rdiv":
            steps.append(mk_div(run, out, None, args[0], wp, cnum=cv[extra]))
        elif kind == "pow":
            e, data = extra
            steps.append(mk_pow(run, out, args[0], cv[e], data, wp))
        elif kind == "sqrt":
            steps.append(mk_sqrt(run, out, args[0], wp))
        elif kind == "exp":
            steps.append(mk_exp(run, out, args[0], wp))
        elif kind == "log":
            steps.append(mk_log(run, out, args[0], wp))
        elif kind in ("sincos", "sinhcosh"):
            steps.append(mk_sincos(run, out[0], out[1], args[0], wp, kind == "sinhcosh"))
        elif kind in ("tan", "tanh"):
            steps.append(mk_tan(run, out[0], out[1], args[0], wp, kind == "tanh"))
        elif kind == "atan":
            steps.append(mk_atan(run, out[0], out[1], args[0], wp))
        else:  # pragma: no cover
            raise AssertionError(kind)
    return steps


def _expand(program, y0_raw, pars_raw, order, wp, s, deadline, checked, sizes=None, measured=None, packs=None):
    """:func:`expand`; None when ``checked`` is false and a packed dot product's fields did not fit every order."""
    plan = jet_plan(program)
    # packed dot products pay off with Python ints up to about 100 digits, with gmpy2 up to about 300
    Z = bigint.integer_type()
    grouped = wp <= (_GMP_GROUP_BITS if Z is not int else _INT_GROUP_BITS)
    instrs, nkeys, to_state, cv = _prepared(plan, grouped, wp, pars_raw)
    run = Run(plan.nslots, wp, Z, sizes)
    J, U = run.J, run.U
    nvars = program.nvars
    is_const = plan.is_const
    for i, e in enumerate(_state_exponents(y0_raw)):
        if sizes is not None and not y0_raw[i][1] and sizes[i] is not None:
            e = min(e, sizes[i])  # a state at zero: F bits below what it carried, where that is finer
        U[i] = e - wp
        J[i] = [to_int(y0_raw[i], U[i])]
    for x in range(nvars, plan.nslots):
        if not is_const[x]:
            J[x] = []
    run.dv = [None] * nkeys
    run.nxt = [None] * nvars
    run.s = s
    run.order = order
    steps = _steps(run, instrs, to_state, cv, wp)
    srcs = []
    fused_out = {o for kind, o, *_ in instrs if kind == "sop" and o in to_state}
    deferred = [(J[to_state[o]], to_state[o]) for o in fused_out]
    nxt = run.nxt
    for i, o in enumerate(plan.outputs):
        if o in fused_out:
            continue
        if is_const[o]:
            srcs.append((J[i], i, None, cv[o]))
        else:
            srcs.append((J[i], i, o, None))

    def rest(k):  # the outputs not fused into their sop
        k1 = k + 1
        for zi, i, o, c in srcs:
            if o is not None:
                zi.append(div_round(J[o][k], k1, U[o] + s - U[i]))
            elif k == 0 and c[1]:
                cs, cm, ce, _ = c
                m = div_round(Z(cm), k1, ce + s - U[i])
                zi.append(-m if cs else m)
            else:
                zi.append(Z(0))

    # Order 0 sets every jet's exponent and the constants of the later orders. Where every step is a dot product of
    # state variables or a sum of products without an offset, it sets them alone and the order loop computes order
    # 0's values with the later orders' (the same integer operations as the steps')
    k0 = 1
    if order > 1 and all(extra is None or not extra[1] for kind, _, _, extra in instrs if kind == "sop") and all(
            (st.__class__ is Dots and max(st.slots) < nvars) or getattr(st, "kind", None) == "sop" for st in steps):
        for st in steps:
            if st.__class__ is Dots:
                st.setup()
            else:
                st(0, False)
        k0 = 0
    elif order:
        for st in steps:
            st(0)
        for zi, i in deferred:
            zi.append(nxt[i])
        rest(0)
    if order > 1:
        run_orders, env = _order_loop(steps, deferred, rest if srcs else None, checked, Z)
        run_orders(k0, order, deadline, env)
        dots = [st for st in steps if st.__class__ is Dots]
        if not checked and not Dots.all_fit(dots, order):
            return None
        if packs is not None:
            packs += [(st.P, st.W, st.slots[1:], st.bb) for st in dots if len(st.Bs) > 1 and max(st.slots[1:]) < nvars]
    if measured is not None:
        measured.fill(run, nvars)
        if measured.sizes is not None:
            measured.errors = _rounding_error(instrs, to_state, cv, plan.outputs, run, measured.sizes)
    return [J[i] for i in range(nvars)], [U[i] for i in range(nvars)]
