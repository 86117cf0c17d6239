"""vision_verify: learn the target's look, then say which laser candidate is the target.

``core`` (histograms, rectangle geometry, choice; no Zenoh), ``model`` (target model
construction and files), ``verifiers/`` (the plugins: histogram, face, meanshift), ``node``
(the Zenoh service). See docs/vision_verify.md.
"""
