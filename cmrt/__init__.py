"""CMRT service: command line entry point and settings."""
