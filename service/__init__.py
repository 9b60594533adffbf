"""HTTP layer: the FastAPI app factory (`service.app.create_app`), schemas, dashboard page."""
