"""The tools a user runs on top of the solver: studies, the stability scenarios and CFL search, advise, compare,
the interactive windows and the config reference generator. None of them is imported by the physics."""
