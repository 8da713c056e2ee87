"""The simulation core: the functional Task API, MJX physics, auto-reset, parity helpers."""
