"""``python -m fusion_eval`` runs the command line."""

from .cli import entry

entry()
