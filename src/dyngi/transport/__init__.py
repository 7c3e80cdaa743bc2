"""Light transport shared by the techniques (DESIGN.md, "Layout by concept"; issue 24).

* :mod:`.path_walk`: one path walk (BSDF sampling + NEE with MIS + Russian roulette) from camera rays
  or from given surface interactions, with per-vertex choices (which vertices count emission, where
  NEE happens, a terminate hook that returns radiance, e.g. a probe lookup);
* :mod:`.mis`: MIS heuristics;
* :mod:`.accumulate`: progressive (running-mean) accumulation of frames;
* :mod:`.restir_di`: ReSTIR DI as a component (candidates, temporal, spatial, shading; the target a
  parameter).

Imports only the layers below (sampling, scene); a probe volume reaches the walk as a hook."""
