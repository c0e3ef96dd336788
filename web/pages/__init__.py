"""The therapist's pages: plain HTML, vanilla JavaScript and CSS served by the FastAPI
app (``routes.router``); all data come from the REST API and ``/ws/live``."""
