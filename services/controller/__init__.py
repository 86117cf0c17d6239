"""controller: the thesis's following rule with limits, and a watchdog.

``core`` holds the rule and the limits, ``node`` the Zenoh adapter and the watchdog timer.
"""
