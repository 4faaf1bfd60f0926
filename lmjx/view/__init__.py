"""`lmjx view`: interactive 3D views in the browser (viser) of a map (`map`, read by
`mapdata`), a trial replayed from its record (`trialrecord`, `replay`, `trial`) and an
evaluation (`evaluation`); shared: the server and the HTML export (`server`), meshes of the
robot's geoms (`shapes`), colours and cameras (`style`), the choices (`options`), reading back
what the server sends (`recording`) and screenshots in headless Chromium (`browser`).
viser is imported only where a view is served: the rest runs without it."""
