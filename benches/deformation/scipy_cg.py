#!/usr/bin/env python3
"""The deformation solve of Stylet side by side with scipy.sparse.linalg.cg.

Reads the 64-cell system `cargo bench --bench deformation` exported with STYLET_BENCH_EXPORT=DIR
(fixed.u8: Dirichlet nodes; u_bc.f64: their values, nodes x 3 components; u_stylet.f64: Stylet's
field after one cold-started frame; meta.json), builds the same discretised Navier-Lame operator
(thesis eq. 4.2.15; central differences, docs/deformation.md), and solves

    (-L_ff) u_f = L_fd u_d

with conjugate gradients (the operator restricted to free nodes is symmetric positive definite)
to the relative residual Stylet's frame reached, then to 1e-6. Usage: scipy_cg.py DIR
"""
import json
import sys
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla


def operator(n, h, mu, lm):
    """L as a sparse (3N x 3N) matrix over all nodes, rows only at interior nodes."""
    N = n ** 3
    idx = np.arange(N).reshape(n, n, n)  # [k, j, i]
    inner = idx[1:-1, 1:-1, 1:-1].ravel()
    s = [1, n, n * n]
    rows, cols, vals = [], [], []

    def add(comp_row, node_offset, comp_col, w):
        rows.append(3 * inner + comp_row)
        cols.append(3 * (inner + node_offset) + comp_col)
        vals.append(np.full(inner.size, w / (h * h)))

    for a in range(3):
        # mu * Laplacian of component a.
        add(a, 0, a, -6.0 * mu)
        for k in range(3):
            add(a, s[k], a, mu)
            add(a, -s[k], a, mu)
        # (lambda + mu) * d2 u_a / dx_a2.
        add(a, 0, a, -2.0 * lm)
        add(a, s[a], a, lm)
        add(a, -s[a], a, lm)
        # (lambda + mu) * mixed d2 u_b / dx_a dx_b.
        for b in range(3):
            if b == a:
                continue
            q = 0.25 * lm
            add(a, s[a] + s[b], b, q)
            add(a, s[a] - s[b], b, -q)
            add(a, -s[a] + s[b], b, -q)
            add(a, -s[a] - s[b], b, q)
    r = np.concatenate(rows)
    c = np.concatenate(cols)
    v = np.concatenate(vals)
    return sp.csr_matrix((v, (r, c)), shape=(3 * N, 3 * N))


def main():
    d = sys.argv[1]
    meta = json.load(open(f"{d}/meta.json"))
    n, h, mu, lm = meta["n"], meta["h_mm"], meta["mu"], meta["lambda_plus_mu"]
    fixed = np.fromfile(f"{d}/fixed.u8", dtype=np.uint8).astype(bool)
    u_bc = np.fromfile(f"{d}/u_bc.f64", dtype="<f8")
    u_st = np.fromfile(f"{d}/u_stylet.f64", dtype="<f8")
    t0 = time.perf_counter()
    L = operator(n, h, mu, lm)
    fixed3 = np.repeat(fixed, 3)
    free = np.flatnonzero(~fixed3)
    dof = np.flatnonzero(fixed3)
    A = (-L[free][:, free]).tocsr()
    b = (L[free][:, dof] @ u_bc[dof])
    build_s = time.perf_counter() - t0
    sym = abs(A - A.T).max()
    res = lambda u: np.linalg.norm(A @ u - b) / np.linalg.norm(b)
    r_st = res(u_st[free])
    print(f"system: {n}^3 nodes, {free.size} unknowns, {A.nnz} non-zeros, |A - A^T| max {sym:.1e}, built in {build_s:.2f} s")
    print(f"Stylet, one cold-started frame: relative residual {r_st:.3e} in {meta['stylet_cold_solve_ms']:.1f} ms (2 threads)")
    for rtol in [r_st, 1e-6]:
        iters = [0]
        def count(_):
            iters[0] += 1
        t = time.perf_counter()
        u, info = spla.cg(A, b, rtol=rtol, maxiter=20000, callback=count)
        ms = (time.perf_counter() - t) * 1e3
        full = np.zeros(3 * n ** 3)
        full[free] = u
        full[dof] = u_bc[dof]
        diff = np.abs(full - u_st).max()
        print(f"scipy cg to {rtol:.1e}: {ms:.1f} ms, {iters[0]} iterations, info {info}, residual {res(u):.3e}, max |u_cg - u_stylet| {diff:.3f} mm")


if __name__ == "__main__":
    main()
