"""coplane.api: read-only HTTP API and live dashboard of one fleet (FastAPI over the Zenoh bus).

`create_app(settings, bus=None)` builds the app; `python -m coplane.api` serves it with uvicorn.
"""
