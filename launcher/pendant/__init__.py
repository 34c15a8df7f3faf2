"""``jara-arm pendant`` (``pendant``): a teach pendant in the browser; its page is ``page.html``."""
