"""[safety]: which candidates the car may drive in a bounded arena, and what it did there.

`limits`: the arena's walls and the rate limits a path must keep, and what a driven log violated.
`risk`: a candidate's risk from the model's rollout fan, and the assessment that admits, cuts or
refuses it. `kinematic_bound`: the worst case that stands in for the fan before any model and
where the model extrapolates. `live_stop`: the walls kept at run time (`stop = "live"`) instead.
The numbers behind the constants are on docs/results/safety.md.
"""
