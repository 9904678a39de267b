"""Experiment scripts: ``python -m experiments.<name>`` writes ``results/<name>/``."""
