"""The perception study (paper §VII-C): stimuli, design and counterbalancing, the PsychoPy
session runner and simulated participants."""
