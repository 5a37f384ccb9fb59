# Bumped whenever a change alters what an episode does with the same route and seed; benchmark runs record it and
# never mix revisions (msfsu_evaluation.closed_loop). 1: routes v3 runs until 2026-11-26, Bullet worlds kept for the
# engine's life (a few dense episodes depended on what the process ran before); 2: new Bullet worlds every episode.
SIMULATOR_REVISION = 2
