"""MCTS-SSAP and MCTS-Random: :mod:`planner.mcts.fast` (array trees searched by the numba kernels
of :mod:`planner.mcts.kernel`) and :mod:`planner.mcts.reference` (the paper's algorithm written
plainly, the quality baseline). Importing this package loads nothing; the modules load numba."""
