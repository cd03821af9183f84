"""Small, dependency-free helpers every layer may use: atomic files, output locks, path and number
checks, and process hygiene (workers that die with their parent, signals that end a run cleanly)."""
