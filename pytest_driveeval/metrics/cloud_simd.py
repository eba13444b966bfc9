"""Vector steps numba does not write from scalar code, as LLVM intrinsics for cloud_jit's frame kernel.

LLVM's cost model keeps a table lookup per point scalar (no gathers) and cannot
vectorise "append the hits"; both are a few vector instructions with AVX-512
(a gather, a compress).  Nor does it vectorise the candidates' box test, whose
operands are gathered by index.  The intrinsics are LLVM's target-independent
``llvm.masked.gather`` and ``llvm.masked.compressstore``: on a CPU
without those instructions LLVM expands them into scalar code with the same result.
"""
from __future__ import annotations

from numba import types
from numba.core import cgutils
from numba.extending import intrinsic
from llvmlite import ir

LANES = 16
_I1, _I8, _I16, _I32, _I64 = ir.IntType(1), ir.IntType(8), ir.IntType(16), ir.IntType(32), ir.IntType(64)
_V32, _VMASK = ir.VectorType(_I32, LANES), ir.VectorType(_I1, LANES)


def _pointer_suffix(ptr_type) -> str:
    """Name suffix of an intrinsic over ``ptr_type``: typed pointers (older LLVM) or opaque ones."""
    return "p0i32" if str(ptr_type).endswith("*") else "p0"


def _splat(builder, value, vtype):
    v = builder.insert_element(ir.Constant(vtype, None), value, ir.Constant(_I32, 0))
    return builder.shuffle_vector(v, ir.Constant(vtype, None), ir.Constant(_V32, None))


def _data(context, builder, array_type, value):
    return context.make_array(array_type)(context, builder, value).data


def _compress_store(builder, values, out, n, mask):
    """``values``'s lanes where ``mask`` holds, packed, to ``out[n:]``.

    ``llvm.masked.compressstore``, which LLVM 15 (numba 0.61's) has; the newer
    compress in registers (``llvm.experimental.vector.compress``, LLVM 19) measured
    no faster here."""
    vtype = values.type
    store = cgutils.get_or_insert_function(
        builder.module, ir.FunctionType(ir.VoidType(), [vtype, out.type, mask.type]),
        f"llvm.masked.compressstore.v{vtype.count}i32")
    builder.call(store, [values, builder.gep(out, [n]), mask])


def _compact(builder, tab, kv, first, out_i, out_v, n):
    """Append (first + lane, table[key]) of the lanes whose table entry is not 0; the new n."""
    # Addresses of the table entries: base + 4 * key, as a vector of pointers.
    v64 = ir.VectorType(_I64, LANES)
    addr = builder.add(_splat(builder, builder.ptrtoint(tab, _I64), v64),
                       builder.shl(builder.sext(kv, v64), ir.Constant(v64, [2] * LANES)))
    ptrs = builder.inttoptr(addr, ir.VectorType(tab.type, LANES))
    gather = cgutils.get_or_insert_function(
        builder.module, ir.FunctionType(_V32, [ptrs.type, _I32, _VMASK, _V32]),
        f"llvm.masked.gather.v16i32.v16{_pointer_suffix(tab.type)}")
    val = builder.call(gather, [ptrs, ir.Constant(_I32, 4), ir.Constant(_VMASK, [1] * LANES), ir.Constant(_V32, None)])
    hit = builder.icmp_unsigned("!=", val, ir.Constant(_V32, None))
    lanes = builder.add(_splat(builder, builder.trunc(first, _I32), _V32), ir.Constant(_V32, list(range(LANES))))
    _compress_store(builder, lanes, out_i, n, hit)
    _compress_store(builder, val, out_v, n, hit)
    popcount = cgutils.get_or_insert_function(builder.module, ir.FunctionType(_I16, [_I16]), "llvm.ctpop.i16")
    hits = builder.call(popcount, [builder.bitcast(hit, _I16)])
    return builder.add(n, builder.zext(hits, n.type))


@intrinsic
def compact16(typingctx, table, keys, b, first, out_idx, out_val, n):
    """Of the 16 cells ``keys[b:b + 16]``, those whose ``table`` entry is not 0 append
    their point index (``first`` + lane) to ``out_idx[n:]`` and their entry to
    ``out_val[n:]``, in lane order; returns the new ``n``.  int32 arrays, ``keys``
    readable 16 past ``b``, the outputs writable 16 past ``n``."""
    sig = types.intp(table, keys, b, first, out_idx, out_val, n)

    def codegen(context, builder, signature, args):
        tab_t, keys_t, _, _, idx_t, val_t, _ = signature.args
        tab, ks = _data(context, builder, tab_t, args[0]), _data(context, builder, keys_t, args[1])
        out_i, out_v = _data(context, builder, idx_t, args[4]), _data(context, builder, val_t, args[5])
        kv = builder.load(builder.bitcast(builder.gep(ks, [args[2]]), _V32.as_pointer()), align=4)
        return _compact(builder, tab, kv, args[3], out_i, out_v, args[6])

    return sig, codegen


def _load_xy(builder, context, rec_t, data, first):
    """x and y of the 16 records from ``first`` on, as two <16 x float> (float32 as cell_of computes)."""
    rec = rec_t.dtype
    # x and y share one type: cloud_jit's record types give x, y and z one float type.
    size, ox, oy, tx = rec.size, rec.offset("x"), rec.offset("y"), rec.typeof("x")
    ftype = ir.FloatType() if tx == types.float32 else ir.DoubleType()
    width = 4 if tx == types.float32 else 8
    base = builder.gep(builder.bitcast(data, _I8.as_pointer()), [builder.mul(first, ir.Constant(first.type, size))])
    if size % width == 0 and ox % width == 0 and oy % width == 0 and size <= 8 * width:
        # Whole records in one wide load, the fields picked out by shuffles (no gathers).
        per = size // width
        wide = ir.VectorType(ftype, LANES * per)
        block = builder.load(builder.bitcast(base, wide.as_pointer()), align=1)  # records may sit anywhere
        pick = [builder.shuffle_vector(block, ir.Constant(wide, None),
                                       ir.Constant(_V32, [o // width + per * lane for lane in range(LANES)]))
                for o in (ox, oy)]
    else:
        v64 = ir.VectorType(_I64, LANES)
        at = builder.add(_splat(builder, builder.ptrtoint(base, _I64), v64),
                         ir.Constant(v64, [size * lane for lane in range(LANES)]))
        vf = ir.VectorType(ftype, LANES)
        pick = []
        for o in (ox, oy):
            ptrs = builder.inttoptr(builder.add(at, ir.Constant(v64, [o] * LANES)), ir.VectorType(ftype.as_pointer(), LANES))
            gather = cgutils.get_or_insert_function(
                builder.module, ir.FunctionType(vf, [ptrs.type, _I32, _VMASK, vf]),
                f"llvm.masked.gather.v16{'f32' if width == 4 else 'f64'}.v16{_float_ptr_suffix(ptrs.type, width)}")
            pick.append(builder.call(gather, [ptrs, ir.Constant(_I32, 1), ir.Constant(_VMASK, [1] * LANES),
                                              ir.Constant(vf, None)]))
    if width == 8:
        pick = [builder.fptrunc(p, ir.VectorType(ir.FloatType(), LANES)) for p in pick]
    return pick


def _float_ptr_suffix(ptr_vector_type, width: int) -> str:
    return ("p0f32" if width == 4 else "p0f64") if str(ptr_vector_type).endswith("*>") else "p0"


@intrinsic
def scan16(typingctx, rec, first, x0, y0, inv, xmax, ymax, gx, table, out_idx, out_val, n):
    """``compact16`` of the cells of the 16 records ``rec[first:first + 16]`` (all present),
    computed as ``cell_of`` does, from the records in place."""
    if not (isinstance(rec, types.Array) and isinstance(rec.dtype, types.Record) and rec.layout == "C"
            and all(isinstance(a, types.Float) for a in (x0, y0, inv, xmax, ymax))):
        return None
    f32 = types.float32  # the grid's constants are float32: wider arguments are rounded to them
    sig = types.intp(rec, first, f32, f32, f32, f32, f32, gx, table, out_idx, out_val, n)

    def codegen(context, builder, signature, args):
        rec_t, tab_t, idx_t, val_t = signature.args[0], signature.args[8], signature.args[9], signature.args[10]
        data = _data(context, builder, rec_t, args[0])
        tab, out_i, out_v = (_data(context, builder, t, a) for t, a in ((tab_t, args[8]), (idx_t, args[9]),
                                                                         (val_t, args[10])))
        vf = ir.VectorType(ir.FloatType(), LANES)
        x, y = _load_xy(builder, context, rec_t, data, args[1])
        cells = []
        for v, origin, top in ((x, args[2], args[5]), (y, args[3], args[6])):
            f = builder.fmul(builder.fsub(v, _splat(builder, origin, vf)), _splat(builder, args[4], vf))
            zero = ir.Constant(vf, None)
            f = builder.select(builder.fcmp_ordered(">", f, zero), f, zero)  # NaN too goes to 0
            lim = _splat(builder, top, vf)
            f = builder.select(builder.fcmp_ordered("<", f, lim), f, lim)
            cells.append(builder.fptosi(f, _V32))
        keys = builder.add(builder.mul(cells[1], _splat(builder, builder.trunc(args[7], _I32), _V32)), cells[0])
        return _compact(builder, tab, keys, args[1], out_i, out_v, args[11])

    return sig, codegen


@intrinsic
def bit(typingctx, cond):
    """A comparison's verdict as an int64 0 or 1 that LLVM cannot see through.

    LLVM turns ``ok = one & (a <= b) & (c <= d)`` into a select on the combined
    condition, and x86's cmov converter then makes that select a branch on a
    comparison that goes either way at random (a point near a box is inside or
    not): a misprediction every other point.  An empty asm statement between the
    comparison and its integer keeps each verdict a setcc, combined with ``and``."""
    if not isinstance(cond, types.Boolean):
        return None

    def codegen(context, builder, signature, args):
        opaque = ir.InlineAsm(ir.FunctionType(_I64, [_I64]), "", "=r,0")
        return builder.call(opaque, [builder.zext(args[0], _I64)])

    return types.int64(cond), codegen


_W = 8  # lanes of boxes8: float64 in a 512-bit register
_V8I32, _V8I64, _V8F64, _V8MASK = (ir.VectorType(t, _W) for t in (_I32, _I64, ir.DoubleType(), _I1))


def _splat8(builder, value, vtype):
    v = builder.insert_element(ir.Constant(vtype, None), value, ir.Constant(_I32, 0))
    return builder.shuffle_vector(v, ir.Constant(vtype, None), ir.Constant(_V8I32, None))


def _gather8(builder, addr, ftype):
    """The 8 values of type ``ftype`` at the byte addresses ``addr`` (<8 x i64>)."""
    vf = ir.VectorType(ftype, _W)
    ptrs = builder.inttoptr(addr, ir.VectorType(ftype.as_pointer(), _W))
    width = 4 if isinstance(ftype, ir.FloatType) else 8
    gather = cgutils.get_or_insert_function(
        builder.module, ir.FunctionType(vf, [ptrs.type, _I32, _V8MASK, vf]),
        f"llvm.masked.gather.v8{'f32' if width == 4 else 'f64'}.v8{_float_ptr_suffix(ptrs.type, width)}")
    return builder.call(gather, [ptrs, ir.Constant(_I32, width), ir.Constant(_V8MASK, [1] * _W), ir.Constant(vf, None)])


def _append8(builder, values, out, n, mask):
    """Append the lanes of ``values`` (<8 x i32>) where ``mask`` holds to ``out[n:]``; the new n."""
    _compress_store(builder, values, out, n, mask)
    popcount = cgutils.get_or_insert_function(builder.module, ir.FunctionType(_I8, [_I8]), "llvm.ctpop.i8")
    return builder.add(n, builder.zext(builder.call(popcount, [builder.bitcast(mask, _I8)]), n.type))


@intrinsic
def boxes8(typingctx, rec, cand, val, t, count, box, zlo, zhi, hits, n_hit, dist, area, n_area, generic, n_gen):
    """cloud_jit's branch-free candidate step for the 8 candidates ``t .. t + 7`` (of which
    the first ``count`` are real), in float64 vectors: for each, ``BoxSet.contains``'s
    expression against the box of its cell, and its squared distance (``dist[t + k]``);
    the positions of the candidates inside their box appended to ``hits[n_hit:]``, the
    points of decided area cells that are in no box and in ``zlo .. zhi`` to
    ``area[n_area:]``, the positions of undecided candidates to ``generic[n_gen:]``.
    Returns the new (n_hit, n_area, n_gen).
    The operations are the scalar ones, one per lane, in the same order and rounding
    (no fused multiply-add), so every verdict is the scalar verdict.  ``cand`` and ``val``
    readable and ``dist`` writable 8 past ``t``; ``cand`` past ``count`` valid indices of
    ``rec``; ``hits``, ``area`` and ``generic`` writable 8 past their n."""
    if not (isinstance(rec, types.Array) and isinstance(rec.dtype, types.Record) and rec.layout == "C"
            and isinstance(box, types.Array) and box.ndim == 2 and box.layout == "C" and box.dtype == types.float64):
        return None
    sig = types.UniTuple(types.intp, 3)(rec, cand, val, t, count, box, types.float64, types.float64, hits, n_hit,
                                        dist, area, n_area, generic, n_gen)

    def codegen(context, builder, signature, args):
        a = signature.args
        data = [_data(context, builder, a[k], args[k]) if isinstance(a[k], types.Array) else None
                for k in range(len(args))]
        recp, candp, valp, t, count, boxp = data[0], data[1], data[2], args[3], args[4], data[5]
        i = builder.load(builder.bitcast(builder.gep(candp, [t]), _V8I32.as_pointer()), align=4)
        v = builder.load(builder.bitcast(builder.gep(valp, [t]), _V8I32.as_pointer()), align=4)
        splat = lambda value, vt=_V8I32: _splat8(builder, value, vt)  # noqa: E731
        bit_of = lambda k: builder.trunc(builder.lshr(v, splat(ir.Constant(_I32, k))), _V8MASK)  # noqa: E731
        one, is_area = bit_of(30), bit_of(29)
        b = builder.select(one, builder.and_(v, splat(ir.Constant(_I32, (1 << 28) - 1))), ir.Constant(_V8I32, None))
        # The point's x, y, z and the box row's columns, gathered.
        rt = a[0].dtype
        ftype = ir.FloatType() if rt.typeof("x") == types.float32 else ir.DoubleType()
        base = splat(builder.ptrtoint(recp, _I64), _V8I64)
        at = builder.add(base, builder.mul(builder.sext(i, _V8I64), splat(ir.Constant(_I64, rt.size), _V8I64)))
        p = []
        for f in "xyz":
            q = _gather8(builder, builder.add(at, splat(ir.Constant(_I64, rt.offset(f)), _V8I64)), ftype)
            p.append(builder.fpext(q, _V8F64) if ftype != ir.DoubleType() else q)
        row = builder.add(splat(builder.ptrtoint(boxp, _I64), _V8I64),
                          builder.mul(builder.sext(b, _V8I64), splat(ir.Constant(_I64, 64), _V8I64)))
        col = [_gather8(builder, builder.add(row, splat(ir.Constant(_I64, 8 * k), _V8I64)), ir.DoubleType())
               for k in range(8)]  # CX, CY, CZ, HX, HY, HZ, COS, SIN
        fabs = cgutils.get_or_insert_function(builder.module, ir.FunctionType(_V8F64, [_V8F64]), "llvm.fabs.v8f64")
        dx, dy = builder.fsub(p[0], col[0]), builder.fsub(p[1], col[1])
        u = builder.fadd(builder.fmul(dx, col[6]), builder.fmul(dy, col[7]))
        w = builder.fsub(builder.fmul(dy, col[6]), builder.fmul(dx, col[7]))
        ok = builder.and_(builder.and_(builder.fcmp_ordered("<=", builder.call(fabs, [u]), col[3]),
                                       builder.fcmp_ordered("<=", builder.call(fabs, [w]), col[4])),
                          builder.fcmp_ordered("<=", builder.call(fabs, [builder.fsub(p[2], col[2])]), col[5]))
        real = builder.icmp_signed("<", ir.Constant(_V8I32, list(range(_W))), splat(builder.trunc(count, _I32)))
        ok = builder.and_(builder.and_(ok, one), real)
        d2 = builder.fadd(builder.fadd(builder.fmul(p[0], p[0]), builder.fmul(p[1], p[1])), builder.fmul(p[2], p[2]))
        builder.store(d2, builder.bitcast(builder.gep(data[10], [t]), _V8F64.as_pointer()), align=8)
        lanes = builder.add(splat(builder.trunc(t, _I32)), ir.Constant(_V8I32, list(range(_W))))
        n_hit = _append8(builder, lanes, data[8], args[9], ok)
        in_z = builder.and_(builder.fcmp_ordered(">=", p[2], splat(args[6], _V8F64)),
                            builder.fcmp_ordered("<=", p[2], splat(args[7], _V8F64)))
        to_area = builder.and_(builder.and_(is_area, builder.not_(ok)), builder.and_(in_z, real))
        n_area = _append8(builder, i, data[11], args[12], to_area)
        undecided = builder.and_(builder.not_(builder.or_(one, is_area)), real)
        n_gen = _append8(builder, lanes, data[13], args[14], undecided)
        return context.make_tuple(builder, signature.return_type, [n_hit, n_area, n_gen])

    return sig, codegen
