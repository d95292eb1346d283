"""otgeo web service: FastAPI over the ``solvers`` library."""

__version__ = "0.1.0"
