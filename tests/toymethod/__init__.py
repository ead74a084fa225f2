"""A toy third method, the proof of the method contract (clrender.contract.MethodSpec): a
sphere of one flat colour. It lives outside the clrender package and reaches the shell only
through the ``clrender.methods`` entry point that tests/test_toy_method.py registers."""
