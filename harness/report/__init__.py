"""What a person reads: the study reports, the plots (convergence, cost frontier, devices, 3D),
the peer figures, and the reports built on studies (cost frontier, branch starts).

May import: every layer below (`core` ... `study`); never `harness.studies` or `harness.cli`.
"""
