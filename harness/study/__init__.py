"""Levels and studies: the one level runner (`engine`), where independent work runs (`executor`),
the one study pipeline (guards, transaction, runs, report, verdict), a convergence study's
measures, adaptive refinement, the hard cases, verification and scale-out.

May import: `core`, `scene`, `mesh`, `run`, `measure`.
"""
