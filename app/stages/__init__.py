"""The engine's per-frame pipeline as stages, each its own module (DESIGN "Per-frame stages").

    precompute (per scene, cached by its config)   ─► receiver_map (pixels <-> receiver vertices)
    per frame:  lighting.frame_sources (source list + representatives)
             ─► shadow_pass (shadow maps of the proxy, occlusion masks on listed pixels)
             ─► object_shading (object-space transfer x SH volume + emitters)
             ─► object_light (light the object reflects onto the room)
             ─► sun (the directional source: its shadow and its bounce), when the scene has one
             ─► compose (second order, HDR or LDR compositing)

app.engine.Engine owns one scene's stages and runs them in this order (Engine._frame_steps).
Stages allocate their buffers at capacity on the first frame of an object shape and reuse them.
"""
