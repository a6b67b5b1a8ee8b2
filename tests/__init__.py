"""SecUAV's tests. Every directory here is a package, so a test module is imported by its full dotted name
(``tests.mitm_proxy.net.test_link``): two files may share a basename in different directories without breaking
collection, and helpers are imported from ``tests.support`` rather than as top-level modules."""
