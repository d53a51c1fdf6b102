"""One module per CLI command group.

Each module imports only ``typer`` at module level and does its heavy imports inside the command
body, so that ``kaleidospec --help`` stays quick.
"""
