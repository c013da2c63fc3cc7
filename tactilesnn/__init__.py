"""tactilesnn: tactile sensor models, spike encoders and spiking classifiers.

Data flows one way: scene -> sensor -> raw stream -> encoder -> spikes -> model -> prediction.
"""

__version__ = "0.1.0"
