"""Repository tools, run as scripts (``python tools/check_layout.py``); a package so that the tests
import them (``from tools.check_layout import check``) without a path hack."""
