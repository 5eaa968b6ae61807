"""Every stage's parameter model (one module per stage, named after it), with its defaults in
one place. Light: pydantic only. Each stage module imports its model from here, and the run
config (``flows/config.py``) composes them without importing the stages."""
