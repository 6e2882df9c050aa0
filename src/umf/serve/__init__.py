"""`umf serve` / `umf view`: generate scenes and play them in 3-D in a local web page."""

from umf.serve.server import App, find_three, make_server, start_in_thread

__all__ = ["App", "find_three", "make_server", "start_in_thread"]
