"""The bases: shape functions and the grids they live on (B-splines on open knot vectors, uGIMP, CPDI, DDMP,
NURBS and the mapped grid) and each particle's stencil of (node, weight, gradient) contributions."""
