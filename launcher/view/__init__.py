"""``jara-arm view``: a web page with a live 3D view of every arm (``view``), each arm drawn by ``scene``."""
