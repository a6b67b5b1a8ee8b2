"""Code the tests share (no tests here): real peers, brokers, streams and benches, imported as
``from tests.support.<module> import ...``. Fixtures stay in the conftest.py beside the tests that use them."""
