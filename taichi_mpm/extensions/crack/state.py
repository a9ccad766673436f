"""The finder's part of a checkpoint: damage (and the damage law's history), and with kept normals the normals,
their positions and drift and the node cache, so that a run continued from a state reuses the same normals as the
one that goes on. Per-particle arrays are stored in creation order."""

import numpy as np

from .constants import ALL, CACHE_KEYS, KEEP, NODE_CACHE_KEYS


def get_state(finder) -> dict:
    f, view = finder.fields, finder.view
    state = {"damage": finder.damage()}
    if f.kappa is not None:
        state["damage_kappa"] = view.to_creation(f.kappa.to_numpy())
    if f.cached:   # a run continued from this state reuses the same normals as the one that goes on
        state.update(crack_normals=view.to_creation(f.n_cache.to_numpy().astype(np.float64)),
                     crack_normal_states=view.to_creation(f.s_cache.to_numpy()),
                     crack_normal_positions=view.to_creation(f.x_ref.to_numpy().astype(np.float64)),
                     crack_normals_stale=int(f.stale[None]),
                     crack_normal_drift=view.to_creation(f.drift.to_numpy().astype(np.float64)))
        state.update(zip(NODE_CACHE_KEYS, node_cache_arrays(finder)))
    return state


def node_cache_arrays(finder):
    """The node cache as (storage indices, normals, flags), sorted by index (the same file for any threads)."""
    f = finder.fields
    k = finder._k["node_cache_size"]()
    idx, nrm, flag = np.zeros((k, f.dim), np.int32), np.zeros((k, f.dim)), np.zeros(k)
    if k:
        f.node_cache_fill[None] = 0
        finder._k["node_cache_read"](idx, nrm, flag)
        order = np.lexsort(idx.T[::-1])
        idx, nrm, flag = idx[order], nrm[order], flag[order]
    return idx, nrm, flag


def check_state(finder, state: dict):
    """Refuse damage arrays of the wrong shape before anything of the state is restored."""
    n = finder.view.n
    for k in ("damage", "damage_kappa"):
        if k in state and np.shape(state[k]) != (n,):
            raise ValueError(f"state {k} must have shape {(n,)}, got {np.shape(state[k])}")


def set_state(finder, state: dict):
    f, view = finder.fields, finder.view
    if "damage" in state:
        f.d.from_numpy(view.to_solver(np.asarray(state["damage"], np.float64)))
    if f.kappa is not None and "damage_kappa" in state:
        f.kappa.from_numpy(view.to_solver(np.asarray(state["damage_kappa"], np.float64)))
    finder.invalidate()
    if f.cached and all(k in state for k in CACHE_KEYS):   # the contact list is derived: rebuilt next step
        _set_kept_normals(finder, state)


def _set_kept_normals(finder, state: dict):
    f, view = finder.fields, finder.view
    n, d = view.n, f.dim
    arrays = [np.asarray(state[k]) for k in CACHE_KEYS[:3] + CACHE_KEYS[4:]]
    if [a.shape for a in arrays] == [(n, d), (n,), (n, d), (n,)] and all(np.isfinite(a).all() for a in arrays):
        f.n_cache.from_numpy(view.to_solver(arrays[0].astype(np.float64)))
        f.s_cache.from_numpy(view.to_solver(arrays[1].astype(np.int32)))
        f.x_ref.from_numpy(view.to_solver(arrays[2].astype(np.float64)))
        f.drift.from_numpy(view.to_solver(arrays[3].astype(np.float64)))
        f.stale[None] = min(max(int(np.asarray(state[CACHE_KEYS[3]])), KEEP), ALL)
        f.node_cache.clear()
        idx, nrm, flag = (np.asarray(state.get(k, ())) for k in NODE_CACHE_KEYS)
        k = len(flag)
        if k and idx.shape == (k, d) and nrm.shape == (k, d) and np.isfinite(nrm).all() and \
                (idx >= 0).all() and (idx < np.array(view.grid.shape)).all():
            finder._k["node_cache_write"](idx.astype(np.int32), nrm.astype(np.float64),
                                          flag.astype(np.float64), k)
        elif k:
            f.stale[None] = ALL   # not a cache this scene can use: recompute all
