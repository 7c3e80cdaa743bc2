"""``dyngi view``: an interactive browser viewer for a scene, its techniques and their probes.

* :mod:`.server` -- the asyncio/websocket server and the ``dyngi view`` entry (:func:`run_viewer`);
  why the ``websockets`` package is in its docstring;
* :mod:`.session` -- the render loop in its worker thread (techniques stepped frame by frame, as
  :func:`dyngi.experiments.runner.run_sequence` does);
* :mod:`.camera` -- orbit and fly camera controls;
* :mod:`.overlays` -- probe spheres with their irradiance, VPLs, octree leaves;
* :mod:`.errorview` -- the reference and HDR-FLIP at low priority in a child process;
* :mod:`.browser` -- headless Chromium over the DevTools protocol (the browser tests);
* ``static/`` -- the page (``index.html``, ``viewer.js``).

The viewer is a consumer at the experiments level: it imports techniques, scenes, experiments and
metrics; nothing below it imports it.
"""
