"""mousedom: optical mice in, planar robot pose out."""

__version__ = "0.1.0"
