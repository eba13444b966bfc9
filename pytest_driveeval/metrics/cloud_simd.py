"""Vector steps numba does not write from scalar code, as LLVM intrinsics for cloud_jit's frame kernel.

LLVM's cost model keeps a table lookup per point scalar (no gathers) and cannot
vectorise "append the hits"; both are a few vector instructions with AVX-512
(a gather, a compressing store).  The intrinsics are LLVM's target-independent
``llvm.masked.gather`` and ``llvm.masked.compressstore``: on a CPU without those
instructions LLVM expands them into scalar code with the same result.
"""
from __future__ import annotations

from numba import types
from numba.core import cgutils
from numba.extending import intrinsic
from llvmlite import ir

LANES = 16
_I1, _I16, _I32, _I64 = ir.IntType(1), ir.IntType(16), ir.IntType(32), ir.IntType(64)
_V32, _VMASK = ir.VectorType(_I32, LANES), ir.VectorType(_I1, LANES)


def _pointer_suffix(ptr_type) -> str:
    """Name suffix of an intrinsic over ``ptr_type``: typed pointers (older LLVM) or opaque ones."""
    return "p0i32" if str(ptr_type).endswith("*") else "p0"


def _splat(builder, value, vtype):
    v = builder.insert_element(ir.Constant(vtype, None), value, ir.Constant(_I32, 0))
    return builder.shuffle_vector(v, ir.Constant(vtype, None), ir.Constant(_V32, None))


def _data(context, builder, array_type, value):
    return context.make_array(array_type)(context, builder, value).data


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
        # Addresses of the table entries: base + 4 * key, as a vector of pointers.
        v64 = ir.VectorType(_I64, LANES)
        addr = builder.add(_splat(builder, builder.ptrtoint(tab, _I64), v64),
                           builder.shl(builder.sext(kv, v64), ir.Constant(v64, [2] * LANES)))
        ptrs = builder.inttoptr(addr, ir.VectorType(tab.type, LANES))
        gather = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(_V32, [ptrs.type, _I32, _VMASK, _V32]),
            f"llvm.masked.gather.v16i32.v16{_pointer_suffix(tab.type)}")
        val = builder.call(gather, [ptrs, ir.Constant(_I32, 4), ir.Constant(_VMASK, [1] * LANES),
                                    ir.Constant(_V32, None)])
        hit = builder.icmp_unsigned("!=", val, ir.Constant(_V32, None))
        lanes = builder.add(_splat(builder, builder.trunc(args[3], _I32), _V32), ir.Constant(_V32, list(range(LANES))))
        store = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(ir.VoidType(), [_V32, out_i.type, _VMASK]),
            "llvm.masked.compressstore.v16i32")
        builder.call(store, [lanes, builder.gep(out_i, [args[6]]), hit])
        builder.call(store, [val, builder.gep(out_v, [args[6]]), hit])
        popcount = cgutils.get_or_insert_function(builder.module, ir.FunctionType(_I16, [_I16]), "llvm.ctpop.i16")
        hits = builder.call(popcount, [builder.bitcast(hit, _I16)])
        return builder.add(args[6], builder.zext(hits, args[6].type))

    return sig, codegen
