"""mcrt's version (a leaf module: importing it starts nothing)."""

__version__ = "0.1.0"
