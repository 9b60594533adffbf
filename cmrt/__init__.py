"""The base package: the one settings module (`cmrt.settings`), the canonical form and hash of
stored documents (`cmrt.canonical`), the HTTP client (`cmrt.client`)."""
