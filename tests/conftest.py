from hypothesis import HealthCheck, settings

# Explicit profile: no deadlines (numba compiles on first call), derandomised so CI is repeatable;
# failing examples print their reproduction blob.
settings.register_profile(
    "hil-ci", deadline=None, derandomize=True, print_blob=True, max_examples=25,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
settings.load_profile("hil-ci")
