import hypothesis

# Property tests jit per example shape; keep them deterministic and within the CI budget.
hypothesis.settings.register_profile("jaxpose", max_examples=25, deadline=None, derandomize=True)
hypothesis.settings.load_profile("jaxpose")
