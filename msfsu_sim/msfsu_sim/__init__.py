# Bumped whenever a change alters what an episode does with the same route and seed; benchmark runs record it and
# never mix revisions (msfsu_evaluation.closed_loop). 1: routes v3 runs until 2026-11-26, Bullet worlds kept for the
# engine's life (a few dense episodes depended on what the process ran before), pedestrians placed by the map's
# seed (the same for every episode seed of a route); 2: new Bullet worlds every episode, pedestrians placed by the
# episode's seed.
SIMULATOR_REVISION = 2
