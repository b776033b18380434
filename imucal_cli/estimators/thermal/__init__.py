"""The bias temperature models: a polynomial per channel, and joint with the gravity-magnitude
model."""
