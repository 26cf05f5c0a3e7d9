"""Examples: each a script (``python examples/<name>.py``) that imports only the installed packages."""
