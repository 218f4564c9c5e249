def main():
    print('stub')
