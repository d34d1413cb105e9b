"""Looking at results: the browser viewer (``jsrte view``) and the HTML report (``jsrte report``).

- :mod:`jsrte.view.loading` reads fit folders, ``fit-many`` outputs, scenes and ``.jsrte`` codes
  into :class:`~jsrte.view.loading.FitItem` objects (mesh, scan, truth, floor, poses, numbers).
- :mod:`jsrte.view.display` prepares them for drawing: subsampled points coloured by distance
  to the fitted surface, meshes decimated for display.
- :mod:`jsrte.view.server` serves an interactive 3D viewer with ``viser``.
- :mod:`jsrte.view.report` writes one self-contained offline HTML file with ``plotly``.
- :mod:`jsrte.view.browser` drives headless Chromium (screenshots, JavaScript errors) for tests
  and benchmarks.
"""
