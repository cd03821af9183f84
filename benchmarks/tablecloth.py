"""The tablecloth trick, measured: how far the top box moves when the bottom box is pulled out at a
given speed, on the Panda and on the idealised hand (both within the Panda's Cartesian limits).

    python benchmarks/tablecloth.py

Empty table; the end-effector is commanded along +x at the given speed (ramped at 13 m/s^2) until the
bottom box is out from under the top box (l1 > 0), then stopped; after 1 s of settling the top box's
horizontal displacement is measured. Its safe set allows 0.10 m (d3) and no flip; a pull that fails
g_dyn at any substep on the way is marked.
"""

from __future__ import annotations

import numpy as np

from safemanip.env.slide_out import SlideOutEnv


def pull(env: SlideOutEnv, speed: float) -> tuple[float, float, bool]:
    _, info = env.reset(seed=0)
    start = env.data.xpos[env.index.top_box_body, :2].copy()
    peak, safe = 0.0, True
    for _ in range(40):
        if info["margins"]["l1"] > 0:
            break
        obs, _, _, _, info = env.step(np.array([speed / env.max_speed, 0.0, 0.0], dtype=np.float32))
        peak = max(peak, float(np.linalg.norm(obs[3:6])))
        safe &= info["margins"]["g_dyn"] >= 0
    for _ in range(20):
        *_, info = env.step(np.zeros(3, dtype=np.float32))
        safe &= info["margins"]["g_dyn"] >= 0
    moved = float(np.linalg.norm(env.data.xpos[env.index.top_box_body, :2] - start))
    return peak, moved, bool(safe)


def main() -> None:
    speeds = (0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.7)
    print(f"{'robot':>6} {'command m/s':>11} {'peak speed':>10} {'top box moved':>13} {'top box safe':>12}")
    for embodiment in ("panda", "hand"):
        env = SlideOutEnv(n_objects=0, embodiment=embodiment)
        for speed in speeds:
            peak, moved, safe = pull(env, speed)
            print(f"{embodiment:>6} {speed:>11.2f} {peak:>10.2f} {moved:>11.3f} m {'yes' if safe else 'NO':>12}")


if __name__ == "__main__":
    main()
