"""DBC files shipped with the drivers (see SOURCES.md); a package so they install with it."""
