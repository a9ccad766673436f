"""Step extensions: features a scene switches on, each plugging into the step's named moments
(`taichi_mpm.step.extensions.Extension`): the crack finder, F-bar, the coloured scatter."""
