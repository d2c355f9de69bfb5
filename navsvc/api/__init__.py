"""The HTTP and WebSocket API (FastAPI): ``create_app(Settings)``; ``navsvc serve`` runs it."""

from navsvc.api.app import create_app
from navsvc.api.settings import Settings

__all__ = ["Settings", "create_app"]
