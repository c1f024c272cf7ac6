"""The simulation core of the env wing as array programs over its state (docs/architecture.md,
"The env wing: one simulation"): each module holds one system, a function of arrays that works
the same on one row and on many."""
