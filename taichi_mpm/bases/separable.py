"""Sums over a tensor stencil by sum factorisation: fewer multiplications for the same sums.

On a tensor-product stencil every G2P sum is sum_i f_0(i_0) f_1(i_1) ... f_{d-1}(i_{d-1}) v_i, each f_a one of
three per-axis rows: the weights N, the weights times the node offsets N r (APIC's B, MLS's gradient) or the
derivatives N' (the velocity gradient). Summed node by node (3D quadratic: 27 nodes) each node forms its weight
and gradient products and adds v_pic, B and grad v: about 32 flops a node. Contracted one axis at a time (the last
first, sub-sums shared between the sums that need them) the same seven families of sums take about half of that
(3D quadratic APIC: 441 against 864 multiply-adds), and no per-node weight product is formed.

`contract` works within one iteration of the stencil's run-time loop (stencil_parts.loops): the unrolled trailing
axes are contracted here; the leading axes, walked at run time, multiply in their factor and the caller adds the
iterations up. With the whole stencil at run time (solver.unroll false) that is the node-by-node sum.

The order of the additions differs from the node-by-node sum: results agree to round-off, not bit for bit.

Physics code only: no CLI, rendering or file I/O here.
"""

from taichi.lang.matrix import make_matrix

from .. import traced

WEIGHT, MOMENT, SLOPE = 0, 1, 2   # per-axis rows: N, N r, N'


def contract(factor, st, o, outer, inner, values, requests):
    """The requested sums over the nodes of one run-time iteration o, as a list of vector expressions.

    factor(st, a, row, i): row (WEIGHT, MOMENT, SLOPE) of axis a at the stencil's node i along it (i a Python
    int on unrolled axes, a run-time index on the others); values[k](off): the vector summed, at the stencil node
    `off`; requests: (k, rows) pairs, rows one per axis: sum over the nodes of prod_a factor(a, rows[a]) values[k].
    """
    dim = len(outer)
    lead = [a for a in range(dim) if outer[a] > 1]
    trail = [a for a in range(dim) if outer[a] == 1]
    assert lead == list(range(len(lead))), "the run-time loop covers leading axes"
    nodes = {tuple(int(inner[j][a]) for a in trail): j for j in range(len(inner))}
    span = {a: 1 + max(t[n] for t in nodes) for n, a in enumerate(trail)}
    loaded, memo, rows_at = {}, {}, {}

    def value(k, t):
        if (k, t) not in loaded:
            loaded[(k, t)] = traced.local(values[k](o + inner[nodes[t]]))
        return loaded[(k, t)]

    def row(a, r, i):
        """Axis a's row r at node i (None: a leading axis, at the run-time index o[a]), formed once per call."""
        if (a, r, i) not in rows_at:
            rows_at[(a, r, i)] = traced.local(factor(st, a, r, traced.at(o, a) if i is None else i))
        return rows_at[(a, r, i)]

    def partial(k, fixed, rows):
        """sum over the trailing axes not yet fixed of their rows' product times values[k] (the last axis first:
        sums shared by requests that differ only in the leading rows are formed once)."""
        if not rows:
            return value(k, fixed)
        key = (k, fixed, rows)
        if key not in memo:
            a = trail[len(fixed)]
            memo[key] = traced.local(traced.total([row(a, rows[0], i) * partial(k, fixed + (i,), rows[1:])
                                                   for i in range(span[a])]))
        return memo[key]

    out = []
    for k, rows in requests:
        s = partial(k, (), tuple(rows[a] for a in trail))
        for a in lead:
            s = row(a, rows[a], None) * s
        out.append(s)
    return out


def unit_rows(dim, axis, r):
    """The rows of the sum whose axis `axis` takes row r and every other axis the weights."""
    return tuple(r if a == axis else WEIGHT for a in range(dim))


def columns(vectors):
    """The matrix whose columns are `vectors` (sum v (x) e_a is column a)."""
    n = len(vectors)
    return make_matrix([[traced.at(vectors[a], c) for a in range(n)] for c in range(n)], float)
