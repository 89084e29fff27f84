"""Weight generator plugins: dense input weights from a mesh and its handles.

(Mean value and harmonic coordinates, bone heat and bounded biharmonic
weights register here.)
"""
