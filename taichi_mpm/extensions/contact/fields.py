"""Multi-field contact's node fields, declared once (layout.main_grid places them in the solver's grid, budget.py
counts them): per velocity field k its mass `contact_m{k}`, momentum (then velocity) `contact_p{k}`, mass gradient
`contact_g{k}` (the interface normal), the moment of its mass about the node `contact_x{k}` (sum w m_p (x_p - x_i):
the gap check's centroid) and, with FLIP's old grid velocity, `contact_o{k}`. They lie apart from the
grid's interleaved fields, in leaf arrays of their own in the same blocks (grid.Grid: `apart`), cleared with it.
Physics code only."""

from dataclasses import dataclass

from ...schemes import get as transfer_scheme


@dataclass(frozen=True)
class ContactNeeds:
    """What decides multi-field contact's fields: the number of velocity fields and whether FLIP keeps v_old."""
    n_fields: int
    flip: bool

    @classmethod
    def of(cls, cfg) -> "ContactNeeds":
        return cls(n_fields=len(set(cfg.contact_fields())), flip=transfer_scheme(cfg.solver.transfer).keeps_old_grid)

    @property
    def grid_vectors(self) -> list[str]:
        kinds = ("p", "g", "x", "o") if self.flip else ("p", "g", "x")
        return [f"contact_{kind}{k}" for k in range(self.n_fields) for kind in kinds]

    @property
    def grid_scalars(self) -> list[str]:
        return [f"contact_m{k}" for k in range(self.n_fields)]
