"""`python -m marlin_temp`: the same as the `marlin-temp` command."""

from .main import app

app(prog_name="marlin-temp")
