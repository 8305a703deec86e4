"""Reporting: every figure (one module draws results, computation never imports
matplotlib), the report of ``biped reproduce`` and the reproduction itself."""
