"""Reference numbers for our reconstruction of the paper's example, computed independently of this
package (separate prototypes of the exact recursion, the Lyapunov solver and the optimiser);
used only by the claims about the paper's own example (scope "paper-example")."""
import numpy as np

EIG_Q = np.array([-0.2, 0.6, 1.0])

#: σ_c thresholds for an increase of tr P(4|3) from m to m+1 (ℓ = 0.25), m = 0..4 (derived)
CARLI_THRESHOLDS = np.array([1.1431, 0.4888, 0.2624, 0.1527, 0.0908])

#: Fig. 1: Carli's filter, ℓ = 0.25, exact tr P(4|3), σ = 1; rows σ_c in the paper grid, columns m = 0..5
FIG1_EXACT = np.array([
    [16.113, 10.453, 9.906, 9.760, 9.711, 9.694],
    [16.113, 10.724, 10.320, 10.306, 10.388, 10.500],
    [16.113, 11.536, 11.561, 11.945, 12.416, 12.915],
    [16.113, 14.785, 16.527, 18.502, 20.531, 22.579],
    [16.113, 20.199, 24.804, 29.429, 34.057, 38.684],
    [16.113, 27.780, 36.392, 44.728, 52.992, 61.232],
    [16.113, 49.438, 69.500, 88.438, 107.092, 125.654],
])

#: Fig. 3: the new filter with corrected-optimal gains, exact tr P(4|3), σ = 1
FIG3_EXACT = np.array([
    [13.827, 11.255, 10.684, 10.388, 10.219, 10.113],
    [13.827, 11.338, 10.737, 10.426, 10.248, 10.137],
    [13.827, 11.585, 10.895, 10.539, 10.335, 10.208],
    [13.827, 12.499, 11.525, 10.988, 10.683, 10.491],
    [13.827, 13.065, 12.262, 11.656, 11.244, 10.957],
    [13.827, 13.372, 12.731, 12.172, 11.753, 11.440],
    [13.827, 13.654, 13.263, 12.835, 12.472, 12.176],
])

#: Fig. 2: (formula, σ_c, m) -> (ℓ*, ζ*)
FIG2_GAINS = {
    ("corrected", 0.0, 1): (0.2309, 0.0), ("corrected", 0.0, 5): (0.2749, 0.0), ("corrected", 0.0, 10): (0.2859, 0.0),
    ("corrected", 0.5, 1): (0.2334, 0.0), ("corrected", 0.5, 5): (0.2762, 0.0),
    ("corrected", 1.0, 1): (0.2359, 0.0822), ("corrected", 1.0, 2): (0.2576, 0.0), ("corrected", 1.0, 10): (0.2891, 0.0),
    ("corrected", 1.5, 1): (0.2176, 0.4455), ("corrected", 1.5, 2): (0.2467, 0.2241), ("corrected", 1.5, 4): (0.2807, 0.0190),
    ("corrected", 2.0, 1): (0.2070, 0.6279), ("corrected", 2.0, 2): (0.2306, 0.4486), ("corrected", 2.0, 10): (0.2949, 0.0439),
    ("corrected", 3.0, 1): (0.1960, 0.7970), ("corrected", 3.0, 5): (0.2535, 0.4220), ("corrected", 3.0, 10): (0.2858, 0.2224),
    ("printed", 1.0, 1): (0.2385, 0.0), ("printed", 1.0, 2): (0.2574, 0.0), ("printed", 1.0, 3): (0.2684, 0.0),
    ("printed", 1.5, 1): (0.2381, 0.1248), ("printed", 1.5, 2): (0.2491, 0.1939), ("printed", 1.5, 3): (0.2687, 0.0822),
    ("printed", 2.0, 1): (0.2245, 0.3756), ("printed", 2.0, 2): (0.2329, 0.4227), ("printed", 2.0, 3): (0.2524, 0.3037),
    ("printed", 3.0, 1): (0.2089, 0.6267), ("printed", 3.0, 2): (0.2135, 0.6611), ("printed", 3.0, 3): (0.2281, 0.5725),
}

#: Fig. 2: (σ_c, m) -> J* with the corrected formula
FIG2_J = {(0.0, 0): 16.575, (0.0, 1): 12.215, (0.0, 5): 10.672, (0.0, 10): 10.411, (0.5, 1): 12.537, (0.5, 10): 10.458,
          (1.0, 1): 13.478, (1.0, 5): 11.039, (1.5, 1): 14.344, (1.5, 10): 10.836, (2.0, 1): 14.896, (2.0, 10): 11.154,
          (3.0, 1): 15.537, (3.0, 5): 12.984, (3.0, 10): 11.856}

#: A doubly stochastic but non-normal 4×4 matrix (||QQᵀ − QᵀQ||_max = 0.3, complex eigenvalues):
#: the counterexample to (16) for merely doubly stochastic Q.
NON_NORMAL_Q = np.array([
    [0.5, 0.5, 0.0, 0.0],
    [0.0, 0.2, 0.8, 0.0],
    [0.3, 0.0, 0.2, 0.5],
    [0.2, 0.3, 0.0, 0.5],
])
