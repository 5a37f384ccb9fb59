# Bumped whenever a change alters what an episode does with the same route and seed; benchmark runs record it and
# never mix revisions (msfsu_evaluation.closed_loop). 1: routes v3 runs until 2026-11-26, Bullet worlds kept for the
# engine's life (a few dense episodes depended on what the process ran before), pedestrians placed by the map's
# seed (the same for every episode seed of a route); 2: new Bullet worlds every episode, pedestrians placed by the
# episode's seed; 3: the lidar's broad-phase detector is made anew in each episode's world (in revision 2 it moved
# into the new world where the last episode left it, and 2 of 350 dense episodes still depended on that); 4: the
# sidewalk texture is drawn without anisotropic filtering (environment.Quality.anisotropic_sidewalks): the same
# episodes for a blind driver (the expert), slightly different far sidewalk pixels for a network.
SIMULATOR_REVISION = 4
UNRECORDED_REVISION = 1  # what a run, report or bag made before revisions were recorded was made with
