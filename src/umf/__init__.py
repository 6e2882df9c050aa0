"""umf: Unified Motion Flow, text + number of people -> synchronized 3-D motion."""

__version__ = "0.1.0"
