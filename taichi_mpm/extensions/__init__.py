"""Step extensions: features a scene switches on, each plugging into the step's named moments
(`taichi_mpm.step.moments.Extension`; their order: `taichi_mpm.step.extensions`): the ddmp pre-pass, the coloured
scatter's binding, the mapped grid's coordinates, F-bar's average, the crack finder."""
