"""The paper's numbers ("None" = the paper gives no number) and its names, quoted from its tables, figures and
text: "Rapid co-design of Buoyancy-assisted robots for Challenging Locomotion using Gaussian Evolutionary
Specialists" (Sinha, Sontakke, Hong, Tanaka and Ha)."""

# Table I "BALLU morphology parameters": (lower, upper, baseline)
PAPER_TABLE1 = {"l_f": (0.25, 0.55, 0.45), "l_t": (0.25, 0.55, 0.45), "gcr": (0.72, 0.90, 0.70),
                "spcf": (0.001, 0.100, 0.002)}
# Table II "Mean Simulation Performance": baseline design, e2e MLP, e2e MoE, GES (cm / degrees)
PAPER_TABLE2 = {("obstacle", "d2"): {"design": 14.2, "mlp": 29.4, "moe": 34.0, "ges": 36.9},
                ("obstacle", "d3"): {"design": 14.2, "mlp": 24.5, "moe": 21.2, "ges": 29.1},
                ("ramp", "d2"): {"design": 25.1, "mlp": 27.9, "moe": 28.4, "ges": 31.4},
                ("ramp", "d3"): {"design": 25.1, "mlp": 28.3, "moe": 27.9, "ges": 29.7}}
# Sec. V-B text: peak scores found by the design search ("GES finds designs that clear a 54 cm obstacle,
# versus 38 cm for e2e MLP and 52 cm for e2e MoE", ...); the ramp 3D peaks are given only as a gain (~8 %).
PAPER_PEAK = {("obstacle", "d2"): {"mlp": 38.0, "moe": 52.0, "ges": 54.0},
              ("obstacle", "d3"): {"mlp": 41.0, "moe": None, "ges": 54.0},
              ("ramp", "d2"): {"mlp": 32.61, "moe": 32.61, "ges": 36.25},
              ("ramp", "d3"): {"mlp": None, "moe": None, "ges": None}}
# Sec. V-B/V-D text: the GES-optimised designs (GCR 0.88, SPCF 0.008 obstacle D2; leg 45.58 cm obstacle D3;
# leg 31.45 cm ramp D3)
PAPER_PEAK_DESIGN = {("obstacle", "d2"): "gcr=0.88 spcf=0.008", ("obstacle", "d3"): "l=0.4558",
                     ("ramp", "d2"): None, ("ramp", "d3"): "l=0.3145"}
# Sec. V-B text: head-to-head win rates of GES over 1000 test designs (%)
PAPER_WINS = {("obstacle", "d2"): {"mlp": 94, "moe": 72}, ("obstacle", "d3"): {"mlp": 68, "moe": 76},
              ("ramp", "d2"): {"mlp": 81, "moe": 78}, ("ramp", "d3"): {"mlp": 75, "moe": 86}}
# Table III "Impact of initialization strategy" (K = 3, obstacle, D2): mean, min, max in cm
PAPER_TABLE3 = {"grid": (29.7, 22, 43), "random": (31.5, 24, 45), "fps": (34.5, 22, 52),
                "fps+lloyd": (35.2, 24, 52)}
# Fig. 7: no numbers in the text, only "Performance peaks at K = 3 and degrades for larger K"
PAPER_KSENS_PEAK_K = 3
# Sec. V-D "Computational Cost": ~100 h per-design BO vs ~63 h GES on the 3D space, a 37 % reduction;
# Stage 1 for K = 6 took 48 h.
PAPER_COST = {"bo_h": 100.0, "ges_h": 63.0, "reduction_pct": 37.0, "stage1_h": 48.0}
CELLS = tuple(PAPER_TABLE2)   # the (task, space) cells of Table II, in the paper's order
# the paper's names of the methods; "baseline" = the baseline design's own policy
METHOD_NAMES = {"baseline": "baseline policy", "mlp": "e2e MLP", "moe": "e2e MoE", "ges": "GES"}

PAPER_TPE_TRIALS = 40   # [facts] the authors' TPE trials per search, the paper's cost comparison
