"""The crack finder's named constants: particle states, refresh levels, contact-list stages and the margins its
searches keep."""

STANDARD, MODIFIED, CONTACT = 0, 1, 2   # particle states: unmodified, cut (tension), cut with normal contact
S_FLOOR = 1e-3                          # a family whose kept weights sum below this keeps standard functions
MAX_CELLS = 1 << 26
CACHE_KEYS = ("crack_normals", "crack_normal_states", "crack_normal_positions", "crack_normals_stale",
              "crack_normal_drift")
KEEP, DRIFTED, ALL = 0, 1, 2            # normals this step: kept / recomputed where they drifted / all recomputed
BIG = 1e30
SLOTS, FILL, OVERFLOW = 0, 1, 2         # the contact lists' build stages (contact_lists.ContactPool.build)
LIST_SLACK = 8                          # slots a contact list gets beyond its last length (+25 %)
DRIFT_LIMIT = 0.5                       # skins: a normal is recomputed once its neighbours may have moved against
                                        # it by this much (the bound a particle's own motion triggers refreshes at)
NODE_CACHE_KEYS = ("crack_node_cache_index", "crack_node_cache_normal", "crack_node_cache_flag")
CELL_SPLIT = 2                          # cell list cells of r/2: a query scans 5^d cells, (2.5 r)^d, not (3 r)^d
ROW_MARGIN = 1e-2                       # cell units: a cell is cut from a search only beyond r + this (rounding)
CONE_MARGIN = 1e-4                      # a cell's normals are ruled out as facing only beyond this (rounding)
