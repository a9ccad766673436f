"""What both interactive windows share (gui.py's ti.GUI window and ggui.py's GGUI one): the help line, the energy
strip chart's box, length and colours, and when a slider counts as moved."""

HELP = "space: pause  s: step  r: reset  c: colour  b: basis  t: transfer  drag: push  arrows: turn (3D)  esc: quit"
CHART = (0.62, 0.06, 0.99, 0.24)   # the energy strip chart's box in window units: x0, y0, x1, y1
CHART_LENGTH = 200                 # frames the chart keeps
CHART_COLOURS = {"kinetic": 0xD62728, "strain": 0x1F77B4, "total": 0x222222}
# a slider "moved" when it differs from the session's value by more than this: the widgets hold float32, so the
# config's 0.99 comes back as 0.99000001 and would otherwise count as a move every frame
SLIDER_TOLERANCE = 1e-6
