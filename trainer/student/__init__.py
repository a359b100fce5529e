"""The diffusion-policy student (paper section III-C): depth + joint state -> a chunk of 8-d actions."""
