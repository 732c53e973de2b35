"""Experiments that reproduce the paper's figures and its Urban Circuit comparison.

Entry point: ``python -m experiments {overlap,scaling,urban,all} [options]`` (see
:mod:`experiments.run`). Results (per-trial CSV, summary CSV and Markdown, PNG plots, maps) go to
``docs/results/`` by default, where docs/results.md links them.
"""
