"""Does the TFL attacked law have the authority it asks for? The test that picks the safe law.

With rotor 2 at f₂ = A the attacked law flies u_f, τ_q and τ_r, and τ_p follows from eq. (6):
τ_p = (u_f − τ_r/d) l/2 − 2lA. The rotor opposite the attacked one carries it: in the
canonical frame (:mod:`tfl_mav.control.allocation`) f₄ = A + τ_p/l, so the law can make
τ_p ∈ [−lA, l(f_max − A)] and no more; the side rotors carry the rest, f₁ + f₃ =
u_f − 2A − τ_p/l, and τ_q = l(f₃ − f₁). When what the law asks for lies outside, the
allocation pins a rotor at 0 or at f_max and the torque the law counted on is not made.

One such tick costs nothing: the ξ/η chains absorb a short shortfall, and the paper's own
signal, A = 0.1t + sin z, asks the law to fly through seconds of A = 0 with f₄ pinned about
half the time. A shortfall that *persists* is different: the roll-rate error grows with the
integral of the missing τ_p, and a dead rotor (A = 0 for good) flips the vehicle within
2.5 s. So the monitor measures the *share of recent ticks* on which a healthy rotor was pinned at
a bound: a first-order average of the indicator over ``WINDOW_S`` (0.2 s, a few times the
ξ chain's slowest time constant, so a single transient does not count), and calls the
authority lost when more than ``LOST_SHARE`` of that window was pinned. The flight computer
then hands the vehicle to the reduced-attitude law (:mod:`tfl_mav.control.safe.recovery`), which
never asks for τ_p.

Reading the command the law produced, not a threshold on A, is what makes the decision the
law's own: an attack of 0.2 N that the law never needs τ_p < −0.05 N m against keeps TFL,
and an attack of 5 N that asks f₄ for more than f_max loses it.
"""

from __future__ import annotations

__all__ = ["LOST_SHARE", "WINDOW_S", "AuthorityMonitor"]

WINDOW_S = 0.2       # averaging time of the pinned indicator (s)
LOST_SHARE = 0.5     # authority lost: f₄ pinned on more than this share of the window
_EPS_N = 1e-6        # a command within this of a bound is pinned there (N)


class AuthorityMonitor:
    """The pinned share of the opposite rotor's command, averaged over ``window_s``.

    ``update(f_opposite_n, dt_s)`` is called on every tick the attacked TFL law flies;
    ``lost`` is then True while the share exceeds ``lost_share``, and ``bound`` says which
    bound held it ("floor": A too small for the τ_p asked, "ceiling": A too large).
    """

    def __init__(self, thrust_max_n: float, *, window_s: float = WINDOW_S,
                 lost_share: float = LOST_SHARE) -> None:
        if not (thrust_max_n > 0.0 and window_s > 0.0 and 0.0 < lost_share < 1.0):
            raise ValueError("AuthorityMonitor: thrust_max_n > 0, window_s > 0 and "
                             f"0 < lost_share < 1 (got {thrust_max_n}, {window_s}, "
                             f"{lost_share})")
        self.thrust_max_n = thrust_max_n
        self.window_s = window_s
        self.lost_share = lost_share
        self.share = 0.0          # pinned share of the window, either bound
        self.ceiling_share = 0.0  # … at f_max only

    def reset(self) -> None:
        """Forget the history (the attacked law starts afresh)."""
        self.share = 0.0
        self.ceiling_share = 0.0

    @property
    def lost(self) -> bool:
        return self.share > self.lost_share

    @property
    def bound(self) -> str:
        return "ceiling" if self.ceiling_share > 0.5 * self.share else "floor"

    def update(self, f_opposite_n: float, f_side1_n: float, f_side3_n: float,
               dt_s: float) -> bool:
        """One tick of the attacked law: its commands (N) to the opposite rotor and to the
        two side rotors (canonical 1 and 3, which make τ_q and the rest of u_f) over the
        period ``dt_s`` (s). Returns :attr:`lost`."""
        k = dt_s / self.window_s
        if not k > 0.0:          # a NaN or non-positive period: no update
            k = 0.0
        elif k > 1.0:
            k = 1.0
        top = self.thrust_max_n - _EPS_N
        # f₄ at f_max, or a side rotor at 0 (f₁ + f₃ = u_f − 2A − τ_p/l: A too large) …
        ceiling = f_opposite_n >= top or f_side1_n <= _EPS_N or f_side3_n <= _EPS_N
        # … or f₄ at 0 (A too small), or a side rotor at f_max
        if ceiling or f_opposite_n <= _EPS_N or f_side1_n >= top or f_side3_n >= top:
            self.share += k * (1.0 - self.share)
        else:
            self.share -= k * self.share
        self.ceiling_share += k * ((1.0 if ceiling else 0.0) - self.ceiling_share)
        return self.share > self.lost_share
