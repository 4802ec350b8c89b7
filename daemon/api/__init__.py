"""The REST service (FastAPI): ``main.create_app`` assembles it, one router module per resource."""
