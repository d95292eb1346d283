"""otgeo web service: FastAPI over the ``solvers`` library."""
