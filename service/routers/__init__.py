"""One router per resource: jobs, cmrts (the library), bases, health, pages."""
