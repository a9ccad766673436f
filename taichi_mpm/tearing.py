"""How many groups a body's particles form on the grid: what the numerical-fracture message says about a stopped body.

The solver's check (Simulation._check_fracture) stops a solid body that spreads further than its particles'
stretch accounts for. That happens two ways: the body tore (clumps apart on the grid, each keeping its F), or it
is still one piece whose F no longer follows its particles (a plate one particle thick). Here the body's points
(particle positions, and the corners of particle domains where the basis has them) are binned into grid cells;
cells that share a node are one group (scipy.ndimage.label with the 3^d neighbourhood). More groups than at
creation: somewhere a whole empty cell opened between its particles. Numpy only; physics code (no CLI, rendering
or I/O).
"""
import numpy as np

MAX_CELLS = 50_000_000   # the dense occupancy box of one body above this: no confirmation (the trigger decides)


def groups(points: np.ndarray, lower: np.ndarray, dx: float):
    """The number of groups of occupied cells (sharing at least a node) among `points` (N, d); None when their box
    of cells exceeds MAX_CELLS."""
    if len(points) == 0:
        return 0
    from scipy import ndimage   # (only for a stopped body: most runs never import it)

    cells = np.floor((np.asarray(points) - lower) / dx).astype(np.int64)
    lo = cells.min(axis=0)
    shape = cells.max(axis=0) - lo + 1
    if np.prod(shape.astype(float)) > MAX_CELLS:
        return None
    occupied = np.zeros(tuple(shape), dtype=bool)
    occupied[tuple((cells - lo).T)] = True
    _, n = ndimage.label(occupied, structure=np.ones((3,) * points.shape[1], dtype=bool))
    return int(n)


def domain_points(x: np.ndarray, corners) -> np.ndarray:
    """The positions (N, d) with each particle's domain corners (N, 2^d, d) where there are any."""
    if corners is None:
        return x
    return np.concatenate([x, np.asarray(corners).reshape(-1, x.shape[1])])
