"""What a run's outputs are worth: the fields read from solution.vtu, the norms and the one norm
table, slopes and rates, the physical checks and their verdict, the grid convergence index, the
comparison with the GetFEM peer, and slices of fields.

May import: `core`, `scene`, `mesh`, `run`.
"""
