"""ordervib node: identification methods, switching model runtime and I/O edges."""

__version__ = "0.1.0"
