"""Readers, one module per file format, and the dataset manifest that ties streams together."""
