"""The audio-to-MUP mapping (paper §VI): MFCC features, phone-class gate, MLP bank, expression
cascade, baselines and the streaming animator. Built in the mapping stage's issue."""
