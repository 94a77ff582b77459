"""The build core: the plan (what to do), the runner (doing it), stamps, the manifest and the locks."""
